"""Production sensors emulated on a reference log: a single-antenna receiver's course and speed, and a
production yaw-rate sensor, drawn from a log's reference yaw rate and sideslip (an INS, an optical
sensor), seeded, and recorded beside the log so that every figure says what was emulated.

The course of a single antenna at the CG is the direction of the velocity, ``yaw + beta``; the yaw is the
reference yaw rate integrated (trapezoidal) from 0 at the first row, so the emulated course and the
reference share one heading. A fix is taken every ``1 / gps_rate`` s from ``gps_offset`` on, at the
first row at or after its time, and is placed ``gps_latency`` s later (the receiver's age of the fix);
course noise is the receiver's horizontal velocity noise over the ground speed,
``gps_velocity_noise * hdop / v`` (Gaussian, per fix), or a fixed ``gps_course_noise`` when given; no
fix below ``gps_min_speed``. The production gyro reads ``(1 + scale) r + bias + noise``, rounded to a
multiple of ``quantum`` when one is given (a CAN signal's resolution).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

import numpy as np

from evstab.plants.errors import EvstabError

from .drivelog import LogFormatError, atomic_write


@dataclass(frozen=True, kw_only=True)
class Emulation:
    """What is emulated on a reference log (SI units; angles in rad)."""

    seed: int = 0
    gps_rate: float = 5.0
    """[Hz] course fixes per second."""
    gps_offset: float = 0.0
    """[s] time of the first fix after the log's first row (a cold start's phase)."""
    gps_velocity_noise: float = 0.04
    """[m/s] horizontal velocity noise per axis at HDOP 1 (course noise = this * hdop / speed)."""
    gps_course_noise: float = 0.0
    """[rad] a fixed course noise per fix instead (0: from the velocity noise)."""
    gps_hdop: float = 1.0
    gps_sats: int = 12
    gps_latency: float = 0.0
    """[s] the fix is logged this long after the instant it describes."""
    gps_min_speed: float = 1.0
    """[m/s] no fix below this ground speed (a single antenna's course is undefined at rest)."""
    gyro: str = "reference"
    """``reference``: the log's yaw rate as it is; ``production``: bias, scale, noise, quantum below."""
    gyro_bias: float = 0.0
    """[rad/s]"""
    gyro_scale: float = 0.0
    """[-] 0.01 reads 1 % high."""
    gyro_noise: float = 0.0
    """[rad/s] white noise per sample."""
    gyro_quantum: float = 0.0
    """[rad/s] resolution of the yaw-rate signal (0: none)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "gyro":
                if v not in ("reference", "production"):
                    raise EvstabError(f"emulation: gyro must be 'reference' or 'production', got {v!r}")
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise EvstabError(f"emulation: '{f.name}' must be a finite number, got {v!r}")
        for name in ("gps_rate",):
            if getattr(self, name) <= 0:
                raise EvstabError(f"emulation: '{name}' must be above 0, got {getattr(self, name)!r}")
        for name in ("gps_offset", "gps_velocity_noise", "gps_course_noise", "gps_hdop", "gps_latency", "gps_min_speed",
                     "gyro_noise", "gyro_quantum"):
            if getattr(self, name) < 0:
                raise EvstabError(f"emulation: '{name}' must be >= 0, got {getattr(self, name)!r}")
        if not -0.2 <= self.gyro_scale <= 0.2:
            raise EvstabError(f"emulation: 'gyro_scale' must be within +-0.2, got {self.gyro_scale!r}")

    def describe(self) -> str:
        """One line for a figure's caption."""
        course = (f"{math.degrees(self.gps_course_noise):.2g} deg" if self.gps_course_noise else
                  f"{self.gps_velocity_noise:g} m/s x HDOP {self.gps_hdop:g} / v")
        gps = f"course {self.gps_rate:g} Hz, noise {course}, latency {self.gps_latency:g} s"
        if self.gyro == "reference":
            return f"{gps}; reference gyro; seed {self.seed}"
        q = f", quantum {math.degrees(self.gyro_quantum):.3g} deg/s" if self.gyro_quantum else ""
        return (f"{gps}; production gyro: bias {self.gyro_bias * 1e3:g} mrad/s, scale {self.gyro_scale * 100:+g} %, "
                f"noise {self.gyro_noise * 1e3:g} mrad/s{q}; seed {self.seed}")


PRODUCTION_GYRO = dict(gyro="production", gyro_bias=3e-3, gyro_scale=0.01, gyro_noise=1.5e-3)
"""An automotive MEMS yaw-rate sensor: 3 mrad/s (0.17 deg/s) bias, +1 % scale error, 1.5 mrad/s noise."""


def reference_signals(log) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(t, yaw_rate, beta, ground speed)`` of a reference log: ``yaw_rate_true`` (else the log's
    ``yaw_rate``), ``beta_true``, ``hypot(vx_true, vy_true)`` (else ``speed / cos(beta)``)."""
    cols = log.columns if hasattr(log, "columns") else log
    src = getattr(log, "source", "log")
    if "beta_true" not in cols or not np.any(np.isfinite(cols["beta_true"])):
        raise LogFormatError(f"{src}: no reference sideslip (column 'beta_true', or 'vx_true' and 'vy_true' in the "
                             f"channel map): nothing to emulate a course from")
    t = np.asarray(cols["t"], float)
    r = np.asarray(cols["yaw_rate_true"] if "yaw_rate_true" in cols else cols["yaw_rate"], float)
    beta = np.asarray(cols["beta_true"], float)
    for name, v in (("yaw rate", r), ("beta_true", beta)):
        bad = np.flatnonzero(~np.isfinite(v))
        if len(bad):
            raise LogFormatError(f"{src}: row {int(bad[0]) + 2}: the reference {name} is not finite")
    if "vx_true" in cols and "vy_true" in cols:
        vg = np.hypot(cols["vx_true"], cols["vy_true"])
    else:
        vg = np.abs(np.asarray(cols["speed"], float)) / np.cos(beta)
    return t, r, beta, vg


def emulate(log, em: Emulation) -> dict:
    """The columns of ``log`` with the emulated sensors: ``gps_course``, ``gps_speed``, ``gps_hdop``,
    ``gps_sats`` and ``yaw_rate`` replaced; the reference kept as ``yaw_rate_true`` and ``beta_true``
    (and ``yaw_true``, the integrated reference yaw rate the course is drawn around)."""
    cols = dict(log.columns if hasattr(log, "columns") else log)
    t, r, beta, vg = reference_signals(log)
    n = len(t)
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(t))])
    rng = np.random.default_rng(em.seed)
    gyro_noise = rng.standard_normal(n)
    # fixes: instants every 1 / rate from the offset, each describing the first row at or after it
    inst = np.arange(t[0] + em.gps_offset, t[-1] + 1e-12, 1.0 / em.gps_rate)
    rows = np.unique(np.searchsorted(t, inst - 1e-9, side="left"))
    rows = rows[rows < n]
    course_noise = rng.standard_normal(len(rows))
    speed_noise = rng.standard_normal(len(rows))
    vv = vg[rows]
    sd = (np.full(len(rows), em.gps_course_noise) if em.gps_course_noise else
          em.gps_velocity_noise * em.gps_hdop / np.maximum(vv, em.gps_min_speed))
    course = yaw[rows] + beta[rows] + sd * course_noise
    speed = vv + em.gps_velocity_noise * em.gps_hdop * speed_noise
    ok = vv >= em.gps_min_speed
    logged = np.searchsorted(t, t[rows] + em.gps_latency - 1e-9, side="left")  # placed where it arrives
    keep = ok & (logged < n)
    out = {k: np.full(n, np.nan) for k in ("gps_course", "gps_speed", "gps_hdop", "gps_sats")}
    out["gps_course"][logged[keep]] = course[keep]
    out["gps_speed"][logged[keep]] = np.maximum(speed[keep], 0.0)
    out["gps_hdop"][logged[keep]] = em.gps_hdop
    out["gps_sats"][logged[keep]] = em.gps_sats
    gyro = r.copy()
    if em.gyro == "production":
        gyro = (1.0 + em.gyro_scale) * r + em.gyro_bias + em.gyro_noise * gyro_noise
        if em.gyro_quantum:
            gyro = np.round(gyro / em.gyro_quantum) * em.gyro_quantum
    cols.update(out)
    cols["yaw_rate"] = gyro
    cols["yaw_rate_true"] = r
    cols["beta_true"] = beta
    cols["yaw_true"] = yaw
    cols.pop("gps_heading", None)  # a dual-antenna heading the reference may carry is not a production sensor
    return cols


def metadata_path(path) -> str:
    """The sidecar that records what was emulated on a log: ``LOG.csv`` -> ``LOG.csv.emulation.json``."""
    return f"{path}.emulation.json"


def write_metadata(path, em: Emulation, source: str) -> None:
    doc = {"format": "evstab-emulation/1", "source": source, "settings": dataclasses.asdict(em),
           "description": em.describe()}
    atomic_write(metadata_path(path), lambda fh: fh.write(json.dumps(doc, indent=2) + "\n"))


def read_metadata(path) -> dict | None:
    """The emulation record beside a log, or None."""
    try:
        with open(metadata_path(path), encoding="utf-8") as fh:
            return json.load(fh)
    except FileNotFoundError:
        return None
    except (OSError, json.JSONDecodeError) as exc:
        raise LogFormatError(f"{metadata_path(path)}: not an emulation record ({exc})") from None
