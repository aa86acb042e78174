"""Sensor faults injected into a drive log (the schema's columns), for tests and the fault study.

Each fault is a frozen description with :meth:`apply` ``(columns, rng) -> (columns, rows)``:
a copy of the columns with the fault in it and the boolean mask of the rows it touched
(where a monitor should raise its flag). Times are seconds of the log's ``t``.

GPS time jumping backwards is a property of the receiver's own time tags, which the
schema does not carry: :func:`nmea_time_backwards` writes it into an NMEA stream
(``evstab convert --nmea`` drops the epoch and flags the row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from evstab.plants.errors import SettingsError


def _rows_in(cols, t0, t1):
    t = cols["t"]
    return np.flatnonzero((t >= t0) & (t < t1))


def _fix_rows(cols, t0, t1):
    rows = _rows_in(cols, t0, t1)
    return rows[np.isfinite(cols["gps_course"][rows])]


@dataclass(frozen=True)
class CourseSpikes:
    """``count`` fixes from ``t0`` on get ``size`` [rad] added, alternating in sign."""

    t0: float
    count: int = 3
    size: float = 0.3
    name: str = "gps course spikes"

    def apply(self, cols, rng):
        out = dict(cols)
        rows = _fix_rows(cols, self.t0, np.inf)[:self.count]
        c = np.array(cols["gps_course"], float)
        c[rows] += self.size * np.where(np.arange(len(rows)) % 2 == 0, 1.0, -1.0)
        out["gps_course"] = c
        return out, _mask(cols, rows)


@dataclass(frozen=True)
class FewSatellites:
    """Fixes in ``[t0, t1)`` come from ``sats`` satellites and are off by up to ``error`` [rad] (uniform)."""

    t0: float
    t1: float
    sats: int = 3
    error: float = 0.2
    name: str = "satellites < 4"

    def apply(self, cols, rng):
        out = dict(cols)
        rows = _fix_rows(cols, self.t0, self.t1)
        s = np.array(cols.get("gps_sats", np.where(np.isfinite(cols["gps_course"]), 9.0, np.nan)), float)
        s[rows] = self.sats
        c = np.array(cols["gps_course"], float)
        c[rows] += rng.uniform(-self.error, self.error, len(rows))
        out["gps_sats"], out["gps_course"] = s, c
        return out, _mask(cols, rows)


@dataclass(frozen=True)
class FrozenGps:
    """Every fix in ``[t0, t1)`` repeats the last fix before ``t0`` (all GPS columns)."""

    t0: float
    t1: float
    name: str = "frozen GPS"

    def apply(self, cols, rng):
        out = dict(cols)
        fixes = np.flatnonzero(np.isfinite(cols["gps_course"]))
        before = fixes[cols["t"][fixes] < self.t0]
        if not len(before):
            raise SettingsError(f"frozen GPS at t = {self.t0} s: no fix before it to repeat")
        last = before[-1]
        rows = _fix_rows(cols, self.t0, self.t1)
        for name in ("gps_course", "gps_speed", "gps_hdop", "gps_sats", "gps_heading"):
            if name in cols:
                v = np.array(cols[name], float)
                v[rows] = v[last]
                out[name] = v
        return out, _mask(cols, rows)


@dataclass(frozen=True)
class GyroStuck:
    """The gyro holds its reading at ``t0`` (or ``value`` [rad/s]) until ``t1``."""

    t0: float
    t1: float
    value: float | None = None
    name: str = "gyro stuck"

    def apply(self, cols, rng):
        out = dict(cols)
        rows = _rows_in(cols, self.t0, self.t1)
        g = np.array(cols["yaw_rate"], float)
        g[rows] = g[rows[0]] if self.value is None else self.value
        out["yaw_rate"] = g
        return out, _mask(cols, rows)


@dataclass(frozen=True)
class GyroBiasStep:
    """The gyro reads ``step`` [rad/s] more from ``t0`` on."""

    t0: float
    step: float = np.deg2rad(1.0)
    name: str = "gyro bias step"

    def apply(self, cols, rng):
        out = dict(cols)
        rows = np.flatnonzero(cols["t"] >= self.t0)
        g = np.array(cols["yaw_rate"], float)
        g[rows] += self.step
        out["yaw_rate"] = g
        return out, _mask(cols, rows)


@dataclass(frozen=True)
class WheelSpeedDropout:
    """The wheel speeds (and so ``speed``) read 0 in ``[t0, t1)``."""

    t0: float
    t1: float
    name: str = "wheel-speed dropout"

    def apply(self, cols, rng):
        out = dict(cols)
        rows = _rows_in(cols, self.t0, self.t1)
        for name in ("speed", "wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"):
            if name in cols:
                v = np.array(cols[name], float)
                v[rows] = 0.0
                out[name] = v
        return out, _mask(cols, rows)


def _mask(cols, rows):
    m = np.zeros(len(cols["t"]), bool)
    m[rows] = True
    return m


def nmea_time_backwards(lines: list[str], epoch_index: int, seconds: float = 1.0) -> list[str]:
    """The NMEA sentences with the time tags of epoch ``epoch_index`` (its RMC and GGA, 0-based in
    the order of appearance) moved ``seconds`` back; checksums recomputed (pynmea2)."""
    import pynmea2

    out, epoch, seen = [], -1, set()
    for line in lines:
        msg = pynmea2.parse(line.strip())
        kind = msg.sentence_type
        if kind in ("RMC", "GGA"):
            stamp = msg.data[0]
            if stamp not in seen:
                seen.add(stamp)
                epoch += 1
            if epoch == epoch_index:
                h, m, s = int(stamp[0:2]), int(stamp[2:4]), float(stamp[4:])
                total = h * 3600 + m * 60 + s - seconds
                hours, rem = divmod(total, 3600)
                minutes, s = divmod(rem, 60)
                fields = list(msg.data)
                fields[0] = f"{int(hours):02d}{int(minutes):02d}{s:05.2f}"
                msg = type(msg)(msg.talker, kind, fields)
        out.append(str(msg))
    return out
