"""NMEA 0183 GNSS logs to the drive-log schema's GPS columns (through pynmea2).

Sentences read (any talker, ``GP``, ``GN``, ``GL``, ...), every checksum verified:

* ``RMC``: time, date, status (``A`` valid), speed over ground [knots], course over
  ground [deg true];
* ``VTG``: course over ground [deg true] and speed [km/h or knots] (used when the
  epoch has no RMC course/speed);
* ``GGA``: time, fix quality (0 = no fix), satellites used, HDOP;
* ``GSA``: fix type (1 = no fix), HDOP (used when the epoch has no GGA);
* ``HDT``: dual-antenna heading [deg true].

An epoch is one receiver time tag: ``RMC`` and ``GGA`` carry it, ``VTG``, ``GSA`` and
``HDT`` belong to the epoch of the last time tag before them. An epoch becomes a fix
when its course is known and nothing marks it invalid (RMC status ``V``, GGA quality
0, GSA fix type 1); otherwise it is kept as an epoch without a course (NaN).

Conventions (docs/models.md): receivers report course clockwise from true north in
degrees; the schema's course is in the yaw sense (counter-clockwise from east, the
simulator's x axis), so ``course = pi/2 - radians(cog)``, unwrapped over the fixes
(continuous). The same for the heading. Speeds in m/s. Time: seconds from 00:00 UTC
of the log's first date (a log crossing midnight keeps counting).
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evstab.plants.errors import EvstabError
from evstab.plants.errors import SettingsError

KNOT = 1852.0 / 3600.0
"""One knot in m/s."""


class NmeaFormatError(EvstabError, ValueError):
    """An NMEA log cannot be read; the message names the file, the line and what was expected."""


@dataclass(frozen=True)
class GpsEpochs:
    """One entry per receiver epoch (NaN where the epoch lacks the value)."""

    t: np.ndarray
    """[s] from 00:00 UTC of the first date in the log."""
    course: np.ndarray
    """[rad] yaw sense, continuous; NaN: no usable course this epoch."""
    speed: np.ndarray
    """[m/s] ground speed."""
    hdop: np.ndarray
    sats: np.ndarray
    heading: np.ndarray
    """[rad] dual-antenna heading, yaw sense, continuous."""
    source: str
    date0: _dt.date | None
    time_fault: np.ndarray | None = None
    """True for an epoch whose time tag went backwards (no course; ``t`` is the previous epoch's)."""

    def __len__(self) -> int:
        return len(self.t)


def yaw_sense(deg_from_north) -> np.ndarray:
    """Receiver angles (deg clockwise from true north) to the yaw sense [rad], unwrapped over the finite
    values (NaN stays NaN)."""
    a = np.pi / 2 - np.radians(np.asarray(deg_from_north, float))
    ok = np.isfinite(a)
    a[ok] = np.unwrap(a[ok])
    return a


def _num(value, where: str, field: str) -> float:
    if value is None or value == "":
        return math.nan
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise NmeaFormatError(f"{where}: field '{field}': {value!r} is not a number") from None
    if not math.isfinite(v):
        raise NmeaFormatError(f"{where}: field '{field}': {value!r} is not a finite number")
    return v


def read_nmea(path) -> GpsEpochs:
    """Read an NMEA 0183 log; errors name the file, the line and the field."""
    import pynmea2

    path = Path(path)
    try:
        text = path.read_bytes().decode("ascii")
    except OSError as exc:
        raise NmeaFormatError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise NmeaFormatError(f"{path}: byte {exc.start}: not ASCII text (NMEA 0183 is ASCII)") from None
    epochs: list[dict] = []
    cur: dict | None = None
    last_good: dict | None = None
    date = date0 = None
    pending_days = 0  # whole days since date0 for epochs whose sentence carried no date
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        where = f"{path}: line {n}"
        if not line.startswith("$"):
            raise NmeaFormatError(f"{where}: expected a sentence starting with '$', got {line[:20]!r}")
        try:
            msg = pynmea2.parse(line, check=True)
        except pynmea2.ChecksumError as exc:
            detail = exc.args[0][0] if exc.args and isinstance(exc.args[0], tuple) else exc.args[0]
            raise NmeaFormatError(f"{where}: {detail} (a corrupted line)") from None
        except (pynmea2.ParseError, ValueError, AttributeError) as exc:
            raise NmeaFormatError(f"{where}: not an NMEA 0183 sentence ({exc})") from None
        kind = msg.sentence_type
        if kind in ("RMC", "GGA"):
            try:
                ts = msg.timestamp
                d = msg.datestamp if kind == "RMC" else None
            except (ValueError, TypeError) as exc:
                raise NmeaFormatError(f"{where}: {kind} time or date: {exc}") from None
            if not isinstance(ts, _dt.time):
                raise NmeaFormatError(f"{where}: {kind} without a time tag")
            if d is not None:
                date = d
                date0 = date0 or d
            secs = ts.hour * 3600 + ts.minute * 60 + ts.second + ts.microsecond * 1e-6
            days = (date - date0).days if (date is not None and date0 is not None) else pending_days
            t = days * 86400 + secs
            if last_good is not None and last_good["t"] > t + 43200:  # midnight passed without a date (GGA only)
                pending_days += 1
                t += 86400
            if cur is None or abs(t - cur["raw"]) > 1e-6:
                if last_good is not None and t < last_good["t"]:
                    # the receiver's time went backwards: this epoch (and its sentences) is dropped,
                    # and the merge flags the row where it arrived (column gps_time_fault)
                    cur = {"t": last_good["t"], "raw": t, "valid": False, "time_fault": True, "line": n}
                else:
                    cur = last_good = {"t": t, "raw": t, "valid": True, "line": n}
                epochs.append(cur)
        elif cur is None:
            continue  # sentences before the first time tag belong to no epoch
        if kind == "RMC":
            if msg.status != "A":
                cur["valid"] = False
            cur["cog"] = _num(msg.true_course, where, "true_course")
            cur["speed"] = _num(msg.spd_over_grnd, where, "spd_over_grnd") * KNOT
        elif kind == "VTG":
            if not math.isfinite(cur.get("cog", math.nan)):
                cur["cog"] = _num(msg.true_track, where, "true_track")
            if not math.isfinite(cur.get("speed", math.nan)):
                kmh = _num(msg.spd_over_grnd_kmph, where, "spd_over_grnd_kmph")
                cur["speed"] = kmh / 3.6 if math.isfinite(kmh) else \
                    _num(msg.spd_over_grnd_kts, where, "spd_over_grnd_kts") * KNOT
        elif kind == "GGA":
            quality = _num(msg.gps_qual, where, "gps_qual")
            if not quality > 0:  # 0 (no fix) or empty
                cur["valid"] = False
            cur["sats"] = _num(msg.num_sats, where, "num_sats")
            cur["hdop"] = _num(msg.horizontal_dil, where, "horizontal_dil")
        elif kind == "GSA":
            if str(msg.mode_fix_type).strip() == "1":
                cur["valid"] = False
            if not math.isfinite(cur.get("hdop", math.nan)):
                cur["hdop"] = _num(msg.hdop, where, "hdop")
        elif kind == "HDT":
            cur["hdt"] = _num(msg.heading, where, "heading")
    if not epochs:
        raise NmeaFormatError(f"{path}: no RMC or GGA sentence, expected at least one epoch with a time tag")
    col = {k: np.array([e.get(k, math.nan) for e in epochs], float) for k in ("t", "cog", "speed", "hdop", "sats",
                                                                           "hdt")}
    valid = np.array([e["valid"] for e in epochs])
    cog = np.where(valid, col["cog"], math.nan)
    for name, lo, hi in (("cog", 0.0, 360.0), ("hdt", 0.0, 360.0), ("speed", 0.0, 200.0), ("hdop", 0.0, 100.0),
                         ("sats", 0.0, 255.0)):
        v = col[name]
        bad = np.flatnonzero(np.isfinite(v) & ((v < lo) | (v > hi)))
        if len(bad):
            e = epochs[bad[0]]
            raise NmeaFormatError(f"{path}: line {e['line']}: {name} {v[bad[0]]!r} outside [{lo:g}, {hi:g}]")
    fault = np.array([e.get("time_fault", False) for e in epochs])
    return GpsEpochs(col["t"], yaw_sense(cog), col["speed"], col["hdop"], col["sats"], yaw_sense(col["hdt"]),
                     str(path), date0, fault)


def write_nmea(path, t, course, speed, *, hdop=None, sats=None, start: float = 12 * 3600.0,
               date: str = "010126") -> int:
    """Write GPS fixes (schema units: course in the yaw sense [rad], speed [m/s]) as NMEA 0183 RMC +
    GGA sentences through pynmea2, one epoch per finite course, receiver time ``start + t`` [s of
    the day, UTC] on ``date`` (DDMMYY; a drive must not cross midnight). For simulated logs
    (studies, tests). Written atomically; returns the number of epochs."""
    import pynmea2

    from .drivelog import atomic_write

    t, course, speed = (np.asarray(a, float) for a in (t, course, speed))
    rows = np.flatnonzero(np.isfinite(course))
    lines = []
    for k in rows:
        ts = round(start + float(t[k]), 2)
        if not 0 <= ts < 86400:
            raise SettingsError(f"write_nmea: fix at t = {t[k]!r} s falls outside the day of 'start'")
        h, rem = divmod(ts, 3600)
        m, sec = divmod(rem, 60)
        hms = f"{int(h):02d}{int(m):02d}{sec:05.2f}"
        cog = (90.0 - math.degrees(float(course[k]))) % 360.0
        knots = float(speed[k]) / KNOT if np.isfinite(speed[k]) else 0.0
        hd = 1.0 if hdop is None or not np.isfinite(hdop[k]) else float(hdop[k])
        ns = 8 if sats is None or not np.isfinite(sats[k]) else int(sats[k])
        lines.append(str(pynmea2.RMC("GP", "RMC", (hms, "A", "4807.038", "N", "01131.000", "E", f"{knots:.3f}",
                                                 f"{cog:.3f}", date, "", ""))))
        lines.append(str(pynmea2.GGA("GP", "GGA", (hms, "4807.038", "N", "01131.000", "E", "1", f"{ns:02d}",
                                                 f"{hd:.1f}", "545.4", "M", "46.9", "M", "", ""))))
    atomic_write(path, lambda fh: fh.write("\r\n".join(lines) + "\r\n"))
    return len(rows)


def merge_onto_imu(imu: dict, gps: GpsEpochs, time_offset: float = 0.0) -> tuple[dict, dict]:
    """The GPS epochs placed on the IMU time base (:func:`toolkit.logs.drivelog.place_on_rows`, with
    ``t_gps - time_offset``). Returns the merged columns and the counts (``placed``, and
    ``before``/``after``: epochs outside the IMU log, dropped; ``time_backwards``: epochs whose
    time tag went backwards, dropped and flagged in the column ``gps_time_fault`` on the row of
    the epoch before them, where they arrived)."""
    from .drivelog import place_on_rows
    t = np.asarray(imu["t"], float)
    fault = getattr(gps, "time_fault", None)
    fault = np.zeros(len(gps.t), bool) if fault is None else np.asarray(fault, bool)
    good = ~fault
    rows, inside, counts = place_on_rows(t, gps.t[good] - time_offset, gps.source)
    out = dict(imu)
    for name, values in (("gps_course", gps.course), ("gps_speed", gps.speed), ("gps_hdop", gps.hdop),
                         ("gps_sats", gps.sats), ("gps_heading", gps.heading)):
        col = np.full(len(t), math.nan)
        col[rows] = values[good][inside]
        out[name] = col
    counts["time_backwards"] = int(fault.sum())
    if fault.any():
        flag = np.zeros(len(t))
        k = np.searchsorted(t, gps.t[fault] - time_offset - 1e-9 * max(1.0, float(np.max(np.abs(t)))))
        k = k[(k < len(t)) & (gps.t[fault] - time_offset >= t[0] - 1e-9)]
        flag[k] = 1.0
        out["gps_time_fault"] = flag
    return out, counts
