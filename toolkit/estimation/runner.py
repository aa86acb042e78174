"""Run a filter design over a whole log: compiled (casadi -> C), casadi VM, or numpy.

The filter step of :mod:`toolkit.estimation.kalman` is traced once with casadi
symbols, rolled out by ``mapaccum`` over chunks of samples and compiled to C; the
time loop then runs inside one C call per chunk, on numpy buffers (no copies).
Without a C compiler the same casadi function runs in casadi's virtual machine;
``backend="numpy"`` runs the pure numpy step in a Python loop (the reference).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import casadi as ca
import numpy as np

from evstab.plants.backend import CASADI, NUMPY
from evstab.plants.errors import ModelError

from ..kernels.compiled import cache_key, load_chunk_library, run_chunks, with_fields
from . import dual_antenna, kalman, kkf, lob, two_stage
from .spec import FilterDesign

CHUNK = 4000


@dataclass(frozen=True)
class Estimate:
    """Estimator outputs over a run, named (see :data:`toolkit.estimation.kalman.OUTPUTS`)."""

    t: np.ndarray
    columns: dict
    method: str
    backend: str
    final: dict | None = None
    """What a later drive may start from (:func:`toolkit.estimation.calibration`): the gyro bias at the last
    row and its standard deviation (from the filter's covariance after the log's last compiled chunk, which
    holds the last row without a fix to the chunk's end: slightly wider than at the last row)."""

    def __getitem__(self, name):
        return self.columns[name]


def _plain(d: FilterDesign):
    """The module of a method with one plain step (no course/no-course variants), else None."""
    return {"lob": lob, "kkf": kkf, "two-stage": two_stage, "dual-antenna": dual_antenna}.get(d.method)


def initial_state(d: FilterDesign, yaw_rate0: float = 0.0, bias=None) -> np.ndarray:
    """The filter state a run starts from (``bias``: see :func:`toolkit.estimation.kalman.initial_state`)."""
    mod = _plain(d)
    if mod is not None:
        if bias is not None:
            raise ModelError(f"'{d.method}' does not start from a calibration")
        return mod.initial_state(d)
    return kalman.initial_state(d, 0.0, yaw_rate0, bias)


def _step_function(d: FilterDesign, tuned: tuple[str, ...] = ()):
    """casadi ``est_step(z, u) -> (z_next, y)``, with ``tuned`` noise settings (names of
    :class:`NoiseSettings` fields) ``est_step(z, u, theta) -> (z_next, y)``: those intensities a
    run-time input (one compiled filter for every value, as the noise fit needs).

    For the Kalman designs the step switches (casadi ``conditional``, a real branch
    in the generated C) between the full step and the step without the course
    update, which is exact on the ~99.5 % of samples that carry no fix.
    """
    nin = kalman.INPUTS.size
    mod = _plain(d)
    th = ca.SX.sym("theta", len(tuned))
    if tuned:
        d = with_fields(d, noise=with_fields(d.noise, **{k: th[i] for i, k in enumerate(tuned)}))
    extra = [th] if tuned else []
    if mod is not None:
        if tuned:
            raise ModelError(f"the noise of '{d.method}' is not a run-time input; fit the Kalman methods' noise")
        z, u = ca.SX.sym("z", mod.STATE_SIZE), ca.SX.sym("u", nin)
        zn, y = mod.step(d, z, u, CASADI)
        return ca.Function("est_step", [z, u], [zn, y], ["z", "u"], ["z_next", "y"])
    size = kalman.layout(d).size
    variants = []
    for with_course in (False, True):
        z, u = ca.SX.sym("z", size), ca.SX.sym("u", nin)
        zn, y = kalman.step(d, z, u, CASADI, with_course=with_course)
        variants.append(ca.Function("est_step_" + ("fix" if with_course else "nofix"), [z, u] + extra, [zn, y]))
    switch = ca.Function.conditional("est_switch", [variants[0]], variants[1])
    zm, um = ca.MX.sym("z", size), ca.MX.sym("u", nin)
    thm = [ca.MX.sym("theta", len(tuned))] if tuned else []
    # index 0 -> no fix, anything else -> the default (full) step
    znm, ym = switch(ca.if_else(um[kalman.INPUTS.index("fix")] > 0.5, 1, 0), zm, um, *thm)
    return ca.Function("est_step", [zm, um] + thm, [znm, ym], ["z", "u"] + (["theta"] if tuned else []),
                       ["z_next", "y"])


class CompiledFilter:
    """A filter design ready to run fast; ``backend`` is ``c``, ``vm`` or ``numpy``."""

    def __init__(self, d: FilterDesign, backend: str = "auto", tuned: tuple[str, ...] = ()):
        self.design = d
        self.tuned = tuple(tuned)
        """Noise settings that are a run-time input of :meth:`run` (``theta``), in this order."""
        if self.tuned and backend == "numpy":
            raise ModelError("a filter with run-time noise settings runs compiled (backend c or vm)")
        self.backend = "numpy" if backend == "numpy" else "vm"
        self._step_fn: ca.Function | None = None
        self._chunk_fn: ca.Function | None = None
        if backend in ("auto", "c"):
            # a compiled filter loads without rebuilding the casadi graph
            self._c = load_chunk_library(cache_key("est", d, CHUNK, self.tuned), lambda: self.chunk_fn, "est_chunk",
                                         required=backend == "c")
            if self._c is not None:
                self.backend = "c"

    @property
    def step_fn(self) -> ca.Function:
        """The casadi step ``(z, u) -> (z_next, y)`` (built on first use)."""
        if self._step_fn is None:
            self._step_fn = _step_function(self.design, self.tuned)
        return self._step_fn

    @property
    def chunk_fn(self) -> ca.Function:
        """``(z0, U) -> (z_end, Y)`` over :data:`CHUNK` samples (built on first use)."""
        if self._chunk_fn is None:
            acc = self.step_fn.mapaccum("est_acc", CHUNK)
            z0, U = ca.MX.sym("z0", self.step_fn.size1_in(0)), ca.MX.sym("U", kalman.INPUTS.size, CHUNK)
            th = [ca.MX.sym("theta", len(self.tuned))] if self.tuned else []
            Z, Y = acc(z0, U, *[ca.repmat(t, 1, CHUNK) for t in th])
            self._chunk_fn = ca.Function("est_chunk", [z0, U] + th, [Z[:, -1], Y], ["z0", "U"] + (["theta"] if th else []),
                                         ["z_end", "Y"])
        return self._chunk_fn

    def run(self, U: np.ndarray, z0: np.ndarray, final_state: bool = False, theta=None):
        """``U`` is (N, len(INPUTS)); returns Y (N, len(OUTPUTS)), with ``final_state`` also the
        filter state after the last sample (N a multiple of :data:`CHUNK` for the compiled backends);
        ``theta``: the values of :attr:`tuned`."""
        if len(self.tuned) != (0 if theta is None else len(theta)):
            raise ModelError(f"theta must give {len(self.tuned)} values ({', '.join(self.tuned)})")
        n = U.shape[0]
        ny = kalman.OUTPUTS.size
        if self.backend == "numpy":
            Y = np.empty((n, ny))
            z = z0.copy()
            d = self.design
            mod = _plain(d)
            for k in range(n):
                if mod is not None:
                    z, Y[k] = mod.step(d, z, U[k], NUMPY)
                else:
                    z, Y[k] = kalman.step(d, z, U[k], NUMPY, with_course=bool(U[k, kalman.INPUTS.index("fix")] > 0.5))
            return (Y, z) if final_state else Y
        consts = [np.ascontiguousarray(theta, float)] if self.tuned else []
        return run_chunks(z0, [U], ny, CHUNK, c_fn=self._c if self.backend == "c" else None,
                          casadi_fn=self.chunk_fn, constants=consts, fix_column=kalman.INPUTS.index("fix"),
                          final_state=final_state)


@lru_cache(maxsize=64)
def compiled_filter(d: FilterDesign, backend: str = "auto", tuned: tuple[str, ...] = ()) -> CompiledFilter:
    return CompiledFilter(d, backend, tuned)


def inputs_from_columns(t, speed, steer, yaw_rate, gps_course, *, yaw_moment=None, gps_hdop=None, gps_sats=None,
                        ay=None, gyro_ok=None, ax=None, gps_speed=None, gps_heading=None,
                        roll_rate=None, gps_roll=None, dt0: float = 1e-3) -> np.ndarray:
    """Build the (N, len(INPUTS)) input array; NaN course = no fix; missing HDOP 1, satellites unknown = usable;
    ``gyro_ok`` (0/1 per sample, e.g. from :mod:`toolkit.estimation.monitor`) defaults to a working gyro."""
    n = len(t)
    U = kalman.INPUTS.zeros(n)
    col = kalman.INPUTS.columns(U)  # views: writing them fills U

    def put(name, values, missing=0.0):
        col[name][:] = missing if values is None else np.nan_to_num(np.asarray(values, float), nan=missing)

    def put_with_validity(name, valid, values):  # a sometimes-present measurement and its 0/1 flag
        if values is not None:
            ok = np.isfinite(values)
            col[name][:], col[valid][:] = np.where(ok, values, 0.0), ok

    col["dt"][0] = dt0 if n < 2 else t[1] - t[0]
    col["dt"][1:] = np.diff(t)
    col["speed"][:], col["steer"][:], col["yaw_rate"][:] = speed, steer, yaw_rate
    put_with_validity("course", "fix", gps_course)
    put("yaw_moment", yaw_moment)
    put("hdop", gps_hdop, 1.0)
    put("sats", gps_sats, 99.0)
    put("ay", ay)
    col["ay_ok"][:] = 0.0 if ay is None else np.isfinite(np.asarray(ay, float))
    put("gyro_ok", gyro_ok, 1.0)
    put("ax", ax)
    put("gps_speed", gps_speed)
    put_with_validity("heading", "heading_valid", gps_heading)
    put("roll_rate", roll_rate)
    col["roll_rate_ok"][:] = 0.0 if roll_rate is None else np.isfinite(np.asarray(roll_rate, float))
    put_with_validity("gps_roll", "gps_roll_valid", gps_roll)
    return U


def log_inputs(cols: dict, dt0: float = 1e-3, gyro_ok=None) -> np.ndarray:
    """The (N, len(INPUTS)) filter inputs of a drive log's columns (see :func:`inputs_from_columns`)."""
    get = cols.get
    return inputs_from_columns(cols["t"], cols["speed"], cols["steer"], cols["yaw_rate"], cols["gps_course"],
                               yaw_moment=get("yaw_moment"), gps_hdop=get("gps_hdop"), gps_sats=get("gps_sats"),
                               ay=get("ay"), gyro_ok=gyro_ok, ax=get("ax"), gps_speed=get("gps_speed"),
                               gps_heading=get("gps_heading"), roll_rate=get("roll_rate"), gps_roll=get("gps_roll"),
                               dt0=dt0)


def quantised_gyro_noise(d: FilterDesign, cols, step: float | None = None) -> FilterDesign:
    """``d`` with its gyro noise widened by the log's yaw-rate resolution where the signal is quantised (its
    smallest step at least the monitor's ``quantised_step``, a CAN signal's): a reading rounded to steps of
    ``q`` is off by up to ``q / 2``, uniformly, so its variance grows by ``q^2 / 12`` (ReV-StED's 1.28 deg/s:
    6.4 mrad/s of standard deviation beside the 4 of a MEMS gyro's noise). ``d`` as it is otherwise. ``step``:
    the monitor's ``quantised_step`` (None: its default), so that the filter and the monitor call one signal
    quantised."""
    from .monitor import MonitorSettings, gyro_quantum
    gyro = np.asarray(cols.get("yaw_rate", []), float)
    gyro = gyro[np.isfinite(gyro)]
    if len(gyro) < 2 or "yaw_rate" not in d.states:
        return d
    q = float(gyro_quantum(gyro)[-1])
    if not (np.isfinite(q) and q >= (MonitorSettings().quantised_step if step is None else step)):
        return d
    return replace(d, noise=replace(d.noise, gyro_std=float(np.hypot(d.noise.gyro_std, q / np.sqrt(12.0)))))


def run_estimator(d: FilterDesign, log, backend: str = "auto", *, monitor=None, bias=None) -> Estimate:
    """Run design ``d`` over a drive log (:class:`toolkit.logs.drivelog.DriveLog` or a mapping of columns).

    ``*_true`` columns are never read. With ``monitor`` (True or a
    :class:`toolkit.estimation.monitor.MonitorSettings`) the log is screened for sensor
    faults first (:mod:`toolkit.estimation.monitor`): the filter gets the cleaned inputs
    and the estimate carries the ``fault_*`` flag columns.
    """
    cols = {k: np.asarray(v, float) for k, v in (log.columns.items() if hasattr(log, "columns") else log.items())
            if not k.endswith("_true")}
    screened = None
    if monitor:
        from .monitor import MonitorSettings, screen
        screened = screen(cols, monitor if isinstance(monitor, MonitorSettings) else None)
        cols = screened.columns
    get = cols.get
    d = quantised_gyro_noise(d, cols, monitor.quantised_step if hasattr(monitor, "quantised_step") else None)
    U = log_inputs(cols, d.dt_nominal, None if screened is None else screened.gyro_ok)
    cf = compiled_filter(d, backend)
    z0 = initial_state(d, float(kalman.INPUTS.columns(U)["yaw_rate"][0]), bias)
    if _plain(d) is None:
        Y, z_end = cf.run(U, z0, final_state=True)
    else:
        Y, z_end = cf.run(U, z0), None
    out = kalman.OUTPUTS.columns(Y)
    if d.method == "double-layer":  # layer 2 on layer 1's (dakf's) sideslip and yaw rate
        from .double_layer import layer2
        l2 = layer2(d.params, cols["t"], get("ax", np.zeros(len(U))), get("ay", np.zeros(len(U))), out["yaw_rate"],
                    get("roll_rate", np.zeros(len(U))), get("gps_speed", np.full(len(U), np.nan)), out["beta"],
                    out["beta_std"])
        out.update({"vx": l2["vx"], "vy": l2["vy"], "roll": l2["roll"]})
    if screened is not None:
        from .monitor import MonitorSettings, estimate_flags
        out.update(estimate_flags(screened, out, monitor if isinstance(monitor, MonitorSettings) else None))
    final = {}
    if z_end is not None and d.bias and "gyro_bias" in d.states:
        P = kalman.layout(d).unpack(z_end).P
        ib = d.index("gyro_bias")
        final = {"gyro_bias": float(out["gyro_bias"][-1]), "gyro_bias_std": float(np.sqrt(P[ib * d.n + ib]))}
    return Estimate(cols["t"], out, d.method, cf.backend, final)
