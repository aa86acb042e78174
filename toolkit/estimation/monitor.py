"""Sensor-fault screening of a drive log before and after the estimator, with one flag column per fault.

Recorded drives have faults the filter's own defences do not cover. :func:`screen`
looks at the log causally (each decision uses only samples up to the row it flags,
so the same logic can run on an ECU) and hands the estimator cleaned inputs;
:func:`estimate_flags` adds the faults that only the filter can see. Flags are 0/1 per
row, named in :data:`FLAGS`:

``fault_gps_spike``
    a usable fix whose innovation was far outside what the filter predicts: normalised
    innovation squared above ``spike_nis`` (4.9 sigma). The filter's gate (99.9 %) rejects
    such a fix, and also 1 good fix in 1000 of a consistent filter (one every 3 min at
    5 Hz), which is not a fault.
``fault_gps_sats``
    a fix from fewer than 4 satellites (the filter does not use it).
``fault_gps_frozen``
    a fix equal, bit for bit, to the previous fix in every GPS column the log has
    (course, speed, HDOP, satellites, heading) while the wheels say the car moves: a
    receiver repeating its last solution. Dropped before the filter. A healthy receiver
    repeats course and speed to its output resolution by chance (NMEA's 0.01 deg and
    0.01 kn: a few in 10^4 fixes at a steady cruise); the cost of that false alarm is one
    dropped fix.
``fault_gps_time``
    a GPS epoch whose receiver time went backwards was dropped at this row (set by
    ``evstab convert --nmea``, column ``gps_time_fault`` of the log).
``fault_gyro_stuck``
    the gyro has repeated one value exactly for ``gyro_stuck_time`` (and at least
    ``gyro_stuck_samples`` samples): rows from then until the value changes. The filter
    runs without its gyro update there (``gyro_ok`` = 0): yaw rate from the model, heading
    from the course fixes. A working MEMS gyro's noise (~0.004 rad/s) is hundreds of its
    quantisation steps, so even a few equal samples in a row do not happen; a logger
    holding a slower gyro's samples repeats values for one sensor period, far below
    the 50 ms default. A quantised signal (steps never below ``quantised_step``: a CAN yaw
    rate) holds its value while the car turns steadily: it counts as stuck only when the lateral
    acceleration over the speed leaves the held value (:func:`gyro_stuck`).
``fault_gyro_bias``
    the filter's bias CUSUM alarmed (see :func:`toolkit.estimation.kalman._bias_watch`) and
    reopened the gyro-bias variance.
``fault_speed_dropout``
    the longitudinal speed fell to (near) zero faster than any car decelerates
    (``speed_jump``) from above ``dropout_speed``, or reads (near) zero while the GPS
    ground speed says the car moves: rows until the reading agrees again with the
    substitute. The estimator gets the substitute: the last good speed integrated with
    ``ax`` when the log has it (held otherwise), replaced by the GPS ground speed at
    each fix that has one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from evstab.plants.errors import SettingsError

FLAGS = ("fault_gps_spike", "fault_gps_sats", "fault_gps_frozen", "fault_gps_time", "fault_gyro_stuck",
         "fault_gyro_bias", "fault_speed_dropout")


@dataclass(frozen=True, kw_only=True)
class MonitorSettings:
    gyro_stuck_time: float = 0.05
    """[s] exactly repeated gyro samples for this long count as a stuck gyro."""
    gyro_stuck_samples: int = 5
    quantised_step: float = 1e-3
    """[rad/s] A gyro signal whose steps are never smaller than this (0.057 deg/s) is a quantised one (a CAN
    signal's resolution): it may hold one value while the car turns steadily."""
    quantised_margin: float = 1.0
    """[m/s^2] A quantised gyro is stuck when the lateral acceleration leaves ``v`` times its held value by
    ``v`` times two steps plus this (steady cornering: ``a_y = v r``; the margin covers ``v`` times the
    sideslip rate, the body's roll and the accelerometer's errors) ..."""
    quantised_stuck_time: float = 0.3
    """[s] ... for this long ..."""
    quantised_min_speed: float = 3.0
    """[m/s] ... above this speed ..."""
    quantised_hold_max: float = 2.0
    """[s] ... or, in a log without ``ay``, when it holds a value this long."""
    speed_jump: float = 15.0
    """[m/s^2] a speed reading falling faster than this (1.5 g, beyond any tire's grip) is not the car."""
    dropout_speed: float = 2.0
    """[m/s] only a fall from above this speed to below ``zero_speed`` counts."""
    zero_speed: float = 0.2
    """[m/s] a reading below this counts as the sensor reading zero."""
    gps_moving: float = 3.0
    """[m/s] a GPS ground speed above this while the wheels read zero is a dropout too."""
    resume_tolerance: float = 1.0
    """[m/s] (or 10 % of the substitute, whichever is larger) a reading this close to the substitute ends a dropout."""
    gps_min_speed: float = 1.0
    """[m/s] below this wheel speed a repeated fix is not called frozen (receivers hold course at rest)."""
    spike_nis: float = 23.928127
    """Normalised innovation squared above which a fix is flagged as a spike: the chi-square (1 dof)
    quantile of 1 - 1e-6, a false flag every 55 h of 5 Hz fixes on a consistent filter."""

    def __post_init__(self) -> None:
        for name in ("gyro_stuck_time", "speed_jump", "dropout_speed", "zero_speed", "gps_moving",
                     "resume_tolerance", "gps_min_speed", "spike_nis", "quantised_step", "quantised_margin",
                     "quantised_stuck_time", "quantised_min_speed", "quantised_hold_max"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise SettingsError(f"monitor setting '{name}' must be a finite number > 0, got {v!r}")
        if int(self.gyro_stuck_samples) < 2:
            raise SettingsError(f"monitor setting 'gyro_stuck_samples' must be >= 2, got {self.gyro_stuck_samples!r}")


@dataclass
class Screened:
    """Cleaned columns for the estimator, the gyro validity per row, and the flags found so far."""

    columns: dict
    gyro_ok: np.ndarray
    flags: dict = field(default_factory=dict)

    def counts(self) -> dict:
        return {k: int(np.sum(v)) for k, v in self.flags.items()}


def _runs(eq: np.ndarray):
    """Start and end (exclusive) of every run of True in ``eq``."""
    d = np.diff(np.concatenate([[0], eq.astype(np.int8), [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def _after(t: np.ndarray, start: int, end: int, duration: float) -> int:
    """The first row of ``start:end`` at which ``duration`` has passed since row ``start`` (``end`` or beyond
    if it does not within)."""
    return start + int(np.searchsorted(t[start:end] - t[start], duration - 1e-12))


def gyro_quantum(gyro: np.ndarray) -> np.ndarray:
    """The gyro signal's resolution as seen up to each row (causal): the smallest nonzero step between
    successive readings so far (inf before the first step). A MEMS gyro's noise makes it tiny; a CAN
    signal's resolution (ReV-StED's yaw rate: 1.28 deg/s) shows as a floor under every step."""
    step = np.abs(np.diff(gyro, prepend=gyro[:1]))
    step[step == 0] = np.inf
    return np.minimum.accumulate(step)


def gyro_stuck(t: np.ndarray, gyro: np.ndarray, s: MonitorSettings, ay=None, speed=None) -> np.ndarray:
    """Rows flagged as a stuck gyro (see the module docstring); causal.

    A signal with a resolution of ``quantised_step`` or more (:func:`gyro_quantum`; a log that starts in a
    held value counts as one) holds one value for as long as the yaw rate stays inside one step: there a
    held value ``g`` of resolution ``q`` is stuck only once the lateral acceleration leaves ``v g`` (steady
    cornering) by ``2 q v + quantised_margin`` for ``quantised_stuck_time`` above ``quantised_min_speed``,
    or, in a log without ``ay``, after ``quantised_hold_max``.
    """
    n = len(gyro)
    flag = np.zeros(n, bool)
    if n < 2:
        return flag
    same = np.zeros(n, bool)
    same[1:] = gyro[1:] == gyro[:-1]  # row k repeats row k - 1
    quantum = gyro_quantum(gyro)
    have_ay = ay is not None and speed is not None
    if have_ay:
        v = np.asarray(speed, float)
        ay = np.asarray(ay, float)
    starts, ends = _runs(same)
    for a, b in zip(starts, ends):
        first = a - 1  # the run of equal values begins one row earlier
        q = quantum[first]
        if q >= s.quantised_step:  # inf: no step seen yet (a log that starts in a held value), judged the same way
            q = q if np.isfinite(q) else s.quantised_step
            if not have_ay:
                k = _after(t, first, b, s.quantised_hold_max)
                if k < b:
                    flag[k:b] = True
                continue
            # in the acceleration the car has: a_y against v times the held rate, two steps and the margin apart
            vv = v[first:b]
            off = (np.abs(vv) > s.quantised_min_speed) & (
                np.abs(ay[first:b] - vv * gyro[first]) > 2.0 * q * np.abs(vv) + s.quantised_margin)  # NaN: not off
            o_starts, o_ends = _runs(off)
            for oa, ob in zip(o_starts, o_ends):
                k = _after(t, first + oa, first + ob, s.quantised_stuck_time)
                if k < first + ob:
                    flag[k:b] = True
                    break
            continue
        # flagged from the row at which both the time and the sample count are reached
        k_time = _after(t, first, b, s.gyro_stuck_time)
        k = max(first + int(s.gyro_stuck_samples) - 1, k_time)
        if k < b:
            flag[k:b] = True
    return flag


def gps_frozen(cols: dict, fix: np.ndarray, s: MonitorSettings) -> np.ndarray:
    """Fix rows equal to the previous fix in every GPS column present, with the car moving."""
    rows = np.flatnonzero(fix)
    flag = np.zeros(len(fix), bool)
    if len(rows) < 2:
        return flag
    same = np.ones(len(rows) - 1, bool)
    for name in ("gps_course", "gps_speed", "gps_hdop", "gps_sats", "gps_heading"):
        if name in cols:
            v = np.asarray(cols[name], float)[rows]
            a, b = v[1:], v[:-1]
            same &= (a == b) | (np.isnan(a) & np.isnan(b))
    moving = np.asarray(cols["speed"], float)[rows[1:]] >= s.gps_min_speed
    flag[rows[1:][same & moving]] = True
    return flag


def speed_dropout(t, speed, s: MonitorSettings, ax=None, gps_speed=None, window: int = 20_000):
    """``(flag, substitute speed)``: rows of a wheel-speed dropout and the speed the estimator gets."""
    n = len(speed)
    flag = np.zeros(n, bool)
    v = np.array(speed, float)
    if n < 2:
        return flag, v
    dt = np.diff(t)
    zero = speed < s.zero_speed
    fall = np.zeros(n, bool)
    fall[1:] = zero[1:] & (speed[:-1] > s.dropout_speed) & ((speed[:-1] - speed[1:]) > s.speed_jump * dt)
    gps = np.zeros(n, bool)
    if gps_speed is not None:
        g = np.asarray(gps_speed, float)
        gps = zero & np.isfinite(g) & (g > s.gps_moving)
    starts = np.flatnonzero(fall | gps)
    acc = None if ax is None else np.nan_to_num(np.asarray(ax, float))
    g_all = None if gps_speed is None else np.asarray(gps_speed, float)
    while len(starts):
        k = int(starts[0])
        # the substitute: the last reading before the dropout (or the GPS speed), then ax-integrated
        if fall[k] or g_all is None:  # fall[0] is never set; without a GPS speed every start is a fall
            v0 = float(speed[k - 1])
        else:
            v0 = float(g_all[k])
        end = _dropout_end(k, v0, speed, dt, acc, g_all, s, flag, v, window)
        starts = starts[starts >= max(end, k + 1)]
    return flag, v


def _dropout_end(k, v0, speed, dt, acc, g_all, s, flag, v, window: int = 20_000) -> int:
    """Walk one dropout from row ``k`` in windows of ``window`` rows (bounded memory and work on a
    long log with many dropouts); fills ``flag`` and ``v``; returns the first row after it."""
    n = len(speed)
    a, first = k, True
    while a < n:
        b = min(n, a + window)
        m = b - a
        steps = np.zeros(m)
        if acc is not None:
            steps[1:] = acc[a:b - 1] * dt[a:b - 1]
        cs = np.cumsum(steps)
        anchor = np.full(m, np.nan)  # speeds the substitute restarts from: v0, then each GPS ground speed
        anchor[0] = v0
        if g_all is not None:
            g = g_all[a:b]
            anchor = np.where(np.isfinite(g) & ((np.arange(m) > 0) | (not first)), g, anchor)
        idx = np.maximum.accumulate(np.where(np.isfinite(anchor), np.arange(m), 0))
        sub = np.maximum(anchor[idx] + (cs - cs[idx]), 0.0)
        agree = np.abs(speed[a:b] - sub) <= np.maximum(s.resume_tolerance, 0.1 * sub)
        if first:
            agree[0] = False  # the row that started the dropout
        if agree.any():
            j = int(np.argmax(agree))
            flag[a:a + j] = True
            v[a:a + j] = sub[:j]
            return a + j
        flag[a:b] = True
        v[a:b] = sub
        # the next window starts from the substitute's last value (integrated one more step)
        v0 = float(sub[-1] + (acc[b - 1] * dt[b - 1] if (acc is not None and b < n) else 0.0))
        a, first = b, False
    return n


def screen(cols: dict, settings: MonitorSettings | None = None) -> Screened:
    """Screen a log's columns (a mapping of arrays: the drive-log schema) before the estimator."""
    s = settings or MonitorSettings()
    t = np.asarray(cols["t"], float)
    n = len(t)
    out = dict(cols)
    course = np.asarray(cols["gps_course"], float)
    fix = np.isfinite(course)
    sats = np.asarray(cols["gps_sats"], float) if "gps_sats" in cols else np.full(n, np.nan)
    flags = {name: np.zeros(n, np.int8) for name in FLAGS}
    flags["fault_gps_sats"][:] = fix & np.isfinite(sats) & (sats < 4)
    frozen = gps_frozen(cols, fix, s)
    flags["fault_gps_frozen"][:] = frozen
    if frozen.any():
        out["gps_course"] = np.where(frozen, np.nan, course)
    if "gps_time_fault" in cols:
        flags["fault_gps_time"][:] = np.nan_to_num(np.asarray(cols["gps_time_fault"], float)) > 0.5
    stuck = gyro_stuck(t, np.asarray(cols["yaw_rate"], float), s, cols.get("ay"), cols.get("speed"))
    flags["fault_gyro_stuck"][:] = stuck
    drop, v = speed_dropout(t, np.asarray(cols["speed"], float), s, cols.get("ax"),
                            cols.get("gps_speed"))
    flags["fault_speed_dropout"][:] = drop
    if drop.any():
        out["speed"] = v
    return Screened(out, (~stuck).astype(float), flags)


def estimate_flags(screened: Screened, est_columns: dict, settings: MonitorSettings | None = None) -> dict:
    """All :data:`FLAGS` for a run: the screening's plus the filter's (spikes, bias alarms)."""
    s = settings or MonitorSettings()
    flags = dict(screened.flags)
    nis = np.asarray(est_columns["nis"], float)
    flags["fault_gps_spike"] = (np.isfinite(nis) & (nis >= s.spike_nis)).astype(np.int8)
    alarm = np.asarray(est_columns.get("bias_alarm", np.zeros(len(nis))), float)
    flags["fault_gyro_bias"] = (np.nan_to_num(alarm) > 0.5).astype(np.int8)
    return flags
