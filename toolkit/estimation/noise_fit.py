"""Noise intensities fitted to a drive log by innovation-based maximum likelihood.

A Kalman filter whose noise model is right has innovations ``nu_k`` that are zero-mean with the
variance it predicts, ``S_k = h P h^T + r``; under Gaussian noise the log's likelihood given the
noise intensities ``theta`` is (up to a constant)

    -2 log L(theta) = sum_k ( log S_k(theta) + nu_k(theta)^2 / S_k(theta) )

over every gyro update (each sample) and every accepted course fix (prediction-error
decomposition; Mehra 1970, Shumway & Stoffer's innovations form). :func:`fit_noise` minimises it
over the gyro noise, the GPS velocity noise and the process-noise intensities of the design's
states, in log space (each within a factor ``e^BOUND`` of its start), with the filter compiled once
with those intensities as a run-time input (one run of the log per evaluation), scipy's
L-BFGS-B and forward differences. The first ``warmup`` seconds (the heading initialising, the
bias converging) do not count.

:func:`write_noise` writes the result as a noise file (TOML, ``[noise]`` with
:class:`NoiseSettings` fields) that ``evstab estimate --noise`` and ``evstab design --noise`` read
(:func:`load_noise`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.optimize

from evstab.plants.errors import DataError, ParameterError

from . import kalman
from .runner import compiled_filter, initial_state, log_inputs
from .spec import LATERAL_STATES, LOOP_METHODS, FilterDesign, NoiseSettings

METHODS = LOOP_METHODS + ("mbkf",)
"""The methods whose noise :func:`fit_noise` fits: those that run the Kalman step of
:mod:`toolkit.estimation.kalman` (its ``gyro_var`` and ``course_var`` outputs)."""
BOUND = 4.0
"""Each fitted intensity stays within a factor e^4 (55) of its start."""
SENSOR = ("gyro_std", "gps_velocity_std")
"""The measurement noises every fit includes."""


def default_parameters(d: FilterDesign) -> tuple[str, ...]:
    """What :func:`fit_noise` fits by default: the sensor noises and the process noise of the
    lateral and disturbance states (the yaw angle has none to speak of, the bias walk is too slow
    to identify on minutes of log)."""
    q = tuple(f"q_{s}" for s in d.states if s in LATERAL_STATES)
    return SENSOR + q if d.hdop_noise else ("gyro_std",) + q


@dataclass(frozen=True)
class NoiseFit:
    """The result of :func:`fit_noise`."""

    parameters: tuple[str, ...]
    start: tuple[float, ...]
    values: tuple[float, ...]
    """The fitted intensities, in :attr:`parameters` order (SI units of :class:`NoiseSettings`)."""
    nll_start: float
    nll: float
    """-2 log L per counted innovation at the start and at the fit."""
    evaluations: int
    converged: bool
    gyro_updates: int
    course_fixes: int
    nis_start: float
    nis: float
    """Mean normalised course innovation squared at the start and at the fit (1 when consistent)."""
    nis_interval: tuple[float, float]
    """The 95 % interval of that mean for ``course_fixes`` consistent fixes (chi-square)."""
    at_bound: tuple[str, ...]
    """Parameters that ended on a bound (the log does not pin them)."""

    def noise(self, base: NoiseSettings) -> NoiseSettings:
        changes: dict[str, Any] = dict(zip(self.parameters, self.values))
        return dataclasses.replace(base, **changes)


def _terms(Y: np.ndarray, t: np.ndarray, warmup: float, gate: float):
    y = kalman.OUTPUTS.columns(Y)
    keep = t >= t[0] + warmup
    gv, gr = y["gyro_var"][keep], y["gyro_resid"][keep]
    cv, nis = y["course_var"][keep], y["nis"][keep]
    fix = np.isfinite(cv) & np.isfinite(nis) & (nis < gate)  # fixes the gate accepts (outliers do not count)
    return gv, gr, cv[fix], nis[fix]


def neg_log_likelihood(Y: np.ndarray, t: np.ndarray, warmup: float, gate: float) -> tuple[float, int, int, float]:
    """(-2 log L per innovation, gyro updates, course fixes, mean NIS) of one filter run's outputs."""
    gv, gr, cv, nis = _terms(Y, t, warmup, gate)
    n = len(gv) + len(cv)
    if len(cv) == 0:
        raise DataError("the log has no usable GPS course fix after the warm-up: nothing to fit the GPS noise to")
    total = np.sum(np.log(gv) + gr * gr / gv) + np.sum(np.log(cv) + nis)
    return float(total / n), len(gv), len(cv), float(np.mean(nis))


def nis_interval(n: int, level: float = 0.95) -> tuple[float, float]:
    """Interval of the mean of ``n`` chi-square(1) values at ``level``."""
    import scipy.stats
    a = (1.0 - level) / 2.0
    return float(scipy.stats.chi2.ppf(a, n) / n), float(scipy.stats.chi2.ppf(1 - a, n) / n)


def fit_noise(d: FilterDesign, log, parameters: tuple[str, ...] | None = None, *, warmup: float = 5.0,
              max_iter: int = 60) -> NoiseFit:
    """Fit ``parameters`` (default :func:`default_parameters`) of ``d``'s noise to a drive log.

    Parameters
    ----------
    d : FilterDesign
        A design of one of :data:`METHODS` (the Kalman filters); its
        noise is the start.
    log : DriveLog or mapping
        The drive log (``*_true`` columns are not read).
    parameters : tuple of str, optional
        :class:`NoiseSettings` fields to fit.
    warmup : float
        Seconds at the start of the log that do not count [s].
    max_iter : int
        L-BFGS-B iterations at most.
    """
    params = default_parameters(d) if parameters is None else tuple(parameters)
    fields = {f.name for f in dataclasses.fields(NoiseSettings)}
    bad = [p for p in params if p not in fields]
    if bad:
        raise ParameterError(f"unknown noise settings {', '.join(bad)}; known: {', '.join(sorted(fields))}")
    cols = {k: np.asarray(v, float) for k, v in (log.columns.items() if hasattr(log, "columns") else log.items())
            if not k.endswith("_true")}
    t = cols["t"]
    if t[-1] - t[0] <= warmup + 1.0:
        raise DataError(f"the log is {t[-1] - t[0]:.1f} s long; the fit needs more than the {warmup:g} s warm-up")
    U = log_inputs(cols, d.dt_nominal)
    # the intensities themselves are fitted: the innovation-adaptive scale, which would move them
    # while the fit does, is off in the fitted filter (and stays as it was in the written noise)
    d = dataclasses.replace(d, noise=dataclasses.replace(d.noise, adapt_rate=0.0))
    cf = compiled_filter(d, "auto", params)
    z0 = initial_state(d, float(kalman.INPUTS.columns(U)["yaw_rate"][0]))
    start = np.array([float(getattr(d.noise, p)) for p in params])
    if np.any(start <= 0):
        raise ParameterError(f"noise settings to fit must start above 0: {dict(zip(params, start))}")
    gate = d.noise.gate
    count = {"n": 0}

    def nll(logv):
        count["n"] += 1
        Y = cf.run(U, z0, theta=np.exp(logv))
        val = neg_log_likelihood(Y, t, warmup, gate)[0]
        return val if np.isfinite(val) else 1e12

    x0 = np.log(start)
    res = scipy.optimize.minimize(nll, x0, method="L-BFGS-B", bounds=[(v - BOUND, v + BOUND) for v in x0],
                                  options={"maxiter": max_iter, "eps": 1e-4})
    vals = np.exp(res.x)
    nll0, _, _, nis0 = neg_log_likelihood(cf.run(U, z0, theta=start), t, warmup, gate)
    nll1, ng, nc, nis1 = neg_log_likelihood(cf.run(U, z0, theta=vals), t, warmup, gate)
    at_bound = tuple(p for p, v, lo in zip(params, res.x, x0) if abs(abs(v - lo) - BOUND) < 1e-6)
    return NoiseFit(params, tuple(float(v) for v in start), tuple(float(v) for v in vals), nll0, nll1,
                    count["n"], bool(res.success), ng, nc, nis0, nis1, nis_interval(nc), at_bound)


def write_noise(path, fit: NoiseFit, base: NoiseSettings, source: str) -> None:
    """The noise file: ``[meta]`` (where it comes from, the fit's figures) and ``[noise]`` (every
    :class:`NoiseSettings` field of ``fit.noise(base)`` that differs from the defaults, and the
    fitted ones)."""
    from ..logs.drivelog import atomic_write
    noise = fit.noise(base)
    default = NoiseSettings()
    keys = [f.name for f in dataclasses.fields(NoiseSettings)
            if f.name in fit.parameters or getattr(noise, f.name) != getattr(default, f.name)]
    lo, hi = fit.nis_interval
    how = (f"innovation maximum likelihood over {fit.gyro_updates} gyro updates and {fit.course_fixes} course fixes: "
           f"-2 log L per innovation {fit.nll_start:.6g} -> {fit.nll:.6g}; mean NIS {fit.nis_start:.3f} -> "
           f"{fit.nis:.3f} (95 % interval [{lo:.3f}, {hi:.3f}])")
    if fit.at_bound:
        how += "; at a bound: " + ", ".join(fit.at_bound)
    lines = ["# Noise intensities for evstab's filters (read by `evstab estimate --noise` and `evstab design --noise`).",
             "[meta]", f"source = {_toml_str(source)}", f"fit = {_toml_str(how)}",
             "", "[noise]"]
    lines += [f"{k} = {float(getattr(noise, k))!r}" for k in keys]
    atomic_write(path, lambda fh: fh.write("\n".join(lines) + "\n"))


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def load_noise(path) -> NoiseSettings:
    """The :class:`NoiseSettings` of a noise file (defaults for the fields it does not set)."""
    import tomllib
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"{path}: no such noise file") from None
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{path}: not TOML ({e})") from None
    unknown = sorted(set(doc) - {"meta", "noise"})
    if unknown or "noise" not in doc:
        raise DataError(f"{path}: a noise file has the tables [meta] and [noise]" +
                        (f"; unknown: {', '.join(unknown)}" if unknown else "; [noise] is missing"))
    fields = {f.name: f for f in dataclasses.fields(NoiseSettings)}
    vals: dict[str, Any] = {}
    for k, v in doc["noise"].items():
        if k not in fields:
            raise DataError(f"{path}: [noise] has no field '{k}'; fields: {', '.join(fields)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise DataError(f"{path}: [noise] {k} must be a finite number, got {v!r}")
        vals[k] = int(v) if k == "max_rejects" else float(v)
    try:
        return NoiseSettings(**vals)
    except Exception as e:  # the settings' own checks (>= 0, ...), with the file named
        raise DataError(f"{path}: {e}") from None
