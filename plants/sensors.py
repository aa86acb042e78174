"""Sensor models: gyro, accelerometers, wheel speeds, steer angle, GPS (single and dual antenna).

Measurements are drawn from the truth signals of a run, with every noise source
seeded from one seed (one independent stream per sensor, so adding a sensor does
not change the others). Units and signs are those of the drive-log schema
(docs/formats.md).

GPS: fixes every ``1 / gps_rate`` s (from ``gps_start``). Each fix reports the
antenna's course ``yaw + atan2(v_y + r x_a, v_x - r y_a)`` (same sense and
reference as yaw, wrapped to (-pi, pi]), its ground speed, HDOP and satellite
count, describing the truth ``gps_latency`` s before the row it appears on. The
horizontal velocity noise is ``gps_velocity_noise * hdop`` [m/s] per axis, so the
course noise is that divided by the ground speed; below ``gps_min_speed`` a
receiver's course is meaningless and is reported as NaN. Outage windows have no
fix at all. The dual-antenna heading is yaw plus white noise at the same rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .backend import NUMPY
from .errors import ModelError
from .params import G


@dataclass(frozen=True, kw_only=True)
class SensorConfig:
    """Noise, bias and placement of the sensors. Defaults: automotive MEMS IMU + CCA-600-like GPS."""

    gyro_noise: float = 0.004
    """Yaw-rate white noise std per sample [rad/s] (0.01 deg/s/sqrt(Hz) at 1 kHz)."""
    gyro_bias: float = 0.0
    """Constant yaw-rate gyro bias [rad/s]."""
    gyro_scale_error: float = 0.0
    """Yaw-rate gyro scale-factor error [-] (0.01 = reads 1 % high)."""
    roll_gyro_noise: float = 0.004
    roll_gyro_bias: float = 0.0
    accel_noise: float = 0.05
    """Accelerometer white noise std per sample [m/s^2]."""
    accel_bias_x: float = 0.0
    accel_bias_y: float = 0.0
    speed_noise: float = 0.02
    """Wheel-speed-derived longitudinal speed noise std [m/s]."""
    wheel_speed_noise: float = 0.05
    """Wheel angular speed noise std [rad/s]."""
    steer_noise: float = 2e-4
    """Road-wheel angle sensor noise std [rad]."""
    gps_rate: float = 5.0
    """GPS fix rate [Hz] (seed 003: 5 Hz)."""
    gps_start: float = 0.0
    gps_latency: float = 0.0
    """Age of each fix when it arrives [s]."""
    gps_velocity_noise: float = 0.04
    """Horizontal velocity noise per axis at HDOP 1 [m/s] (0.14 deg course RMS at 60 km/h, seed 003)."""
    gps_hdop: float = 0.9
    gps_sats: int = 10
    gps_min_speed: float = 0.5
    """Below this ground speed [m/s] the course is reported as NaN."""
    gps_outages: tuple[tuple[float, float], ...] = ()
    """(start, end) windows [s] with no fix."""
    gps_antenna_x: float = 0.0
    """Antenna position ahead of the CG [m] (lever arm)."""
    gps_antenna_y: float = 0.0
    """Antenna position left of the CG [m]."""
    heading_noise: float = np.deg2rad(0.1)
    """Dual-antenna heading noise std [rad] (seed 000: 0.1 deg)."""
    roll_noise: float = np.deg2rad(0.3)
    """Dual-antenna roll noise std [rad] (a lateral baseline about a third of the heading's: 0.3 deg).
    The ``gps_roll`` column (body roll + road bank, seed 002) is written by whole-run measurement only."""

    def __post_init__(self) -> None:
        for name in ("gyro_noise", "roll_gyro_noise", "accel_noise", "speed_noise", "wheel_speed_noise",
                     "steer_noise", "gps_latency", "gps_velocity_noise", "heading_noise", "roll_noise", "gps_min_speed"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ModelError(f"sensor setting '{name}' must be >= 0, got {v!r}")
        if not (np.isfinite(self.gps_rate) and self.gps_rate > 0):
            raise ModelError(f"sensor setting 'gps_rate' must be > 0 Hz, got {self.gps_rate!r}")
        if not self.gps_hdop > 0:
            raise ModelError(f"sensor setting 'gps_hdop' must be > 0, got {self.gps_hdop!r}")
        for win in self.gps_outages:
            if len(win) != 2 or not win[1] > win[0]:
                raise ModelError(f"GPS outage window {win!r} must be (start, end) with end > start")


STREAMS = ("gyro", "roll_gyro", "accel", "speed", "wheel", "steer", "gps", "heading", "gps_roll")
"""One noise stream per sensor; a stream added at the end leaves the others' draws unchanged
(``SeedSequence.spawn`` children are keyed by their index)."""


def _streams(seed: int) -> dict[str, np.random.Generator]:
    children = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return {name: np.random.default_rng(s) for name, s in zip(STREAMS, children)}


def wrap_angle(a):
    """Wrap to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(a, float), 2 * np.pi)


def gps_fix_mask(t: np.ndarray, cfg: SensorConfig) -> np.ndarray:
    """Boolean mask of the samples that carry a GPS fix.

    A fix is due at ``gps_start + k / gps_rate``; it lands on the first sample at or
    after that time (so any sample rate, fixed or varying, works). Outage windows
    ``[start, end)`` remove fixes.
    """
    t = np.asarray(t, float)
    k = np.floor((t - cfg.gps_start) * cfg.gps_rate + 1e-9)
    mask = (t >= cfg.gps_start - 1e-12) & (np.concatenate([[-1.0], k[:-1]]) != k)
    for a, b in cfg.gps_outages:
        mask &= ~((t >= a) & (t < b))
    return mask


STREAM_ROWS = {"steer": 1, "gyro": 1, "roll_gyro": 1, "accel": 2, "speed": 1, "wheel": 4, "gps": 2, "heading": 1,
               "gps_roll": 1}
"""Rows of standard-normal draws per sample of each stream (:func:`draw_noise`)."""


def noise_rows(seed: int, n: int, streams: tuple[str, ...]) -> np.ndarray:
    """The draws of :func:`draw_noise` for ``streams`` alone, stacked in that order as the rows of one
    ``(rows, n)`` array (a stream of several rows gives them in its order): the same numbers, drawn
    straight into place, and the streams not asked for not drawn."""
    unknown = [s for s in streams if s not in STREAM_ROWS]
    if unknown:
        raise ModelError(f"unknown noise stream(s) {', '.join(unknown)}; known: {', '.join(STREAMS)}")
    rng = _streams(seed)
    out = np.empty((sum(STREAM_ROWS[s] for s in streams), n))
    r = 0
    for name in streams:
        k = STREAM_ROWS[name]
        rng[name].standard_normal(out=out[r] if k == 1 else out[r:r + k])  # shape (n) or (k, n), as draw_noise draws
        r += k
    return out


def draw_noise(cfg: SensorConfig, seed: int, n: int) -> dict:
    """All noise of a run of ``n`` samples, drawn once (one stream per sensor)."""
    return {name: g.standard_normal(n if STREAM_ROWS[name] == 1 else (STREAM_ROWS[name], n))
            for name, g in _streams(seed).items()}


def readings(tr: dict, inp: dict, nz: dict, gps: tuple, fix, cfg: SensorConfig, wheel_radius: float | None,
             o=NUMPY) -> dict:
    """The sensor equations, numpy (arrays) or casadi (one sample): truth -> readings.

    ``tr`` truth signals, ``inp`` applied ``steer``/``yaw_moment`` and road ``bank``,
    ``nz`` the standard-normal draws of these samples, ``gps`` the truth the fixes
    describe (``yaw, vx, vy, yaw_rate`` at ``t - gps_latency``), ``fix`` 1 where a fix
    is due. GPS values are returned with ``gps_valid`` (fix due and ground speed
    above ``gps_min_speed``) instead of NaN, so that casadi can carry them.
    """
    out = {
        "steer": inp["steer"] + cfg.steer_noise * nz["steer"],
        "yaw_moment": inp["yaw_moment"],
        "yaw_rate": (1.0 + cfg.gyro_scale_error) * tr["yaw_rate"] + cfg.gyro_bias + cfg.gyro_noise * nz["gyro"],
        "roll_rate": tr["roll_rate"] + cfg.roll_gyro_bias + cfg.roll_gyro_noise * nz["roll_gyro"],
    }
    # Accelerometers on the sprung mass: specific force, gravity enters through roll + bank.
    out["ax"] = tr["ax"] + cfg.accel_bias_x + cfg.accel_noise * nz["accel_x"]
    out["ay"] = (tr["ay"] * o.cos(tr["roll"]) + G * o.sin(tr["roll"] + inp["bank"]) + cfg.accel_bias_y
                 + cfg.accel_noise * nz["accel_y"])
    # Wheel speeds and the longitudinal speed from the non-driven (front) wheels.
    for i, w in enumerate(("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")):
        out[w] = tr[w] + cfg.wheel_speed_noise * nz["wheel"][i]
    v_front = tr["vx"] if wheel_radius is None else 0.5 * (tr["wheel_speed_fl"] + tr["wheel_speed_fr"]) * wheel_radius
    out["speed"] = v_front + cfg.speed_noise * nz["speed"]
    # GPS: the antenna's velocity, rotated to the earth frame, with noise there
    yaw, vx, vy, r = gps
    vx_a, vy_a = vx - r * cfg.gps_antenna_y, vy + r * cfg.gps_antenna_x
    ve = vx_a * o.cos(yaw) - vy_a * o.sin(yaw)
    vn = vx_a * o.sin(yaw) + vy_a * o.cos(yaw)
    sigma = cfg.gps_velocity_noise * cfg.gps_hdop
    ve_m, vn_m = ve + sigma * nz["gps_e"], vn + sigma * nz["gps_n"]
    ground = o.sqrt(ve_m * ve_m + vn_m * vn_m)
    course = o.arctan2(vn_m, ve_m)
    out["gps_valid"] = fix * o.if_else(ground >= cfg.gps_min_speed, 1.0, 0.0)
    out["gps_fix"] = fix
    out["gps_course"] = o.arctan2(o.sin(course), o.cos(course))
    out["gps_speed"] = ground
    out["gps_heading"] = yaw + cfg.heading_noise * nz["heading"]
    return out


def _noise_at(noise: dict, idx) -> dict:
    return {"steer": noise["steer"][idx], "gyro": noise["gyro"][idx], "roll_gyro": noise["roll_gyro"][idx],
            "accel_x": noise["accel"][0, idx], "accel_y": noise["accel"][1, idx],
            "wheel": [noise["wheel"][i, idx] for i in range(4)], "speed": noise["speed"][idx],
            "gps_e": noise["gps"][0, idx], "gps_n": noise["gps"][1, idx], "heading": noise["heading"][idx]}


def measure(t: np.ndarray, truth: dict, inputs: dict, cfg: SensorConfig, seed: int,
            wheel_radius: float | None, noise: dict | None = None, index=None) -> dict:
    """Sensor readings for a run (or, with ``index``, for the samples ``index`` of it).

    ``truth`` holds the plant's named truth outputs (arrays over ``t``; with
    ``index`` they need only reach the last index), ``inputs`` the applied
    ``steer``, ``yaw_moment`` and road ``bank`` at the same samples. Returns
    drive-log columns (NaN where a GPS row has no fix). The per-sample form used by
    closed loops reads exactly the same noise as the whole-run form.
    """
    t = np.asarray(t, float)
    n = len(t)
    noise = draw_noise(cfg, seed, n) if noise is None else noise
    idx = np.arange(n) if index is None else np.atleast_1d(np.asarray(index))
    last = int(idx.max()) + 1
    tr = {k: np.asarray(v, float)[idx] for k, v in truth.items()}
    inp = {k: (np.broadcast_to(np.asarray(v, float), (n,))[idx] if np.ndim(v) else np.full(len(idx), float(v)))
           for k, v in inputs.items()}
    inp.setdefault("bank", np.zeros(len(idx)))
    if wheel_radius is not None and not np.all(np.isfinite(tr["wheel_speed_fl"])):
        wheel_radius = None  # models without wheels: the speed sensor reads vx
    t_meas = t[idx] - cfg.gps_latency
    th = t[:last]
    gps = tuple(np.interp(t_meas, th, np.asarray(truth[k], float)[:last]) for k in ("yaw", "vx", "vy", "yaw_rate"))
    # the fix mask at a sample needs only that sample and the one before it
    lo = max(int(idx.min()) - 1, 0)
    fix = gps_fix_mask(t[lo:last], cfg)[idx - lo].astype(float)
    out = readings(tr, inp, _noise_at(noise, idx), gps, fix, cfg, wheel_radius)
    roll_noise = noise["gps_roll"][idx] if "gps_roll" in noise else None
    return log_columns(out, cfg, tr["roll"] + inp["bank"], roll_noise)


def log_columns(out: dict, cfg: SensorConfig, roll_and_bank, roll_noise=None) -> dict:
    """Drive-log columns from :func:`readings`' arrays: GPS values NaN on rows without a (valid) fix,
    HDOP and satellites on fix rows, the heading wrapped, and with ``roll_noise`` (standard-normal
    draws) the dual-antenna roll, the body's roll plus the road's bank (``roll_and_bank``)."""
    out = dict(out)
    valid, fixed = np.asarray(out.pop("gps_valid")) > 0.5, np.asarray(out.pop("gps_fix")) > 0.5
    nan = np.full(len(valid), np.nan)
    out["gps_course"] = np.where(valid, out["gps_course"], nan)
    out["gps_speed"] = np.where(fixed, out["gps_speed"], nan)
    out["gps_hdop"] = np.where(fixed, cfg.gps_hdop, nan)
    out["gps_sats"] = np.where(fixed, float(cfg.gps_sats), nan)
    out["gps_heading"] = np.where(fixed, wrap_angle(out["gps_heading"]), nan)
    if roll_noise is not None:
        out["gps_roll"] = np.where(fixed, roll_and_bank + cfg.roll_noise * roll_noise, nan)
    return out
