"""ASAM MDF4 (``.mf4``) logs to the drive-log schema, through asammdf and a channel map.

The channel map is a small TOML file, one table per schema column::

    [options]
    time_base = "yaw_rate"          # the column whose channel's timestamps are the rows (the IMU)

    [speed]
    channel = "VehSpd"              # channel name in the MDF file
    unit = "km/h"                   # its unit as logged (checked against the file's, when it has one)
    scale = 0.2777777777777778      # schema value = scale * logged + offset
    offset = 0.0

    [gps_course]
    channel = "GNSS_COG"
    unit = "deg"
    angle = "cw-from-north-deg"     # receiver convention: converted to the yaw sense in rad, continuous

Alignment: the rows are the time-base channel's samples. Other continuous channels
(``speed``, ``steer``, accelerations, wheel speeds, ...) are interpolated linearly
onto them, never extrapolated (a row outside a channel's span is an error for a
required column, NaN otherwise). GPS columns (``gps_*``) are placed, not
interpolated: each sample on the first row at or after its time
(:func:`toolkit.logio.place_on_rows`), so no fix is invented between real ones.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from .logio import REQUIRED, SCHEMA, DriveLog, LogFormatError, check_ranges, place_on_rows
from .nmea import yaw_sense

COLUMNS = tuple(c for c, _, _ in SCHEMA if c != "t")
GPS_COLUMNS = ("gps_course", "gps_speed", "gps_hdop", "gps_sats", "gps_heading")
ANGLE_CONVENTIONS = ("cw-from-north-deg",)
_KEYS = {"channel", "unit", "scale", "offset", "angle"}


def load_channel_map(path) -> dict:
    """Read and check a channel map; errors name the file and the key."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise LogFormatError(f"{path}: cannot read: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise LogFormatError(f"{path}: not a TOML file ({exc})") from None
    opts = doc.pop("options", {})
    unknown_opts = set(opts) - {"time_base"}
    if unknown_opts:
        raise LogFormatError(f"{path}: [options]: unknown key '{sorted(unknown_opts)[0]}'; known: time_base")
    out = {}
    for col, spec in doc.items():
        where = f"{path}: [{col}]"
        if col not in COLUMNS:
            raise LogFormatError(f"{where}: unknown schema column; known: {', '.join(COLUMNS)}")
        if not isinstance(spec, dict):
            raise LogFormatError(f"{where}: expected a table with 'channel' (and 'unit', 'scale', 'offset')")
        bad = set(spec) - _KEYS
        if bad:
            raise LogFormatError(f"{where}: unknown key '{sorted(bad)[0]}'; known: {', '.join(sorted(_KEYS))}")
        if not isinstance(spec.get("channel"), str) or not spec["channel"]:
            raise LogFormatError(f"{where}: missing key 'channel' (the channel name in the MDF file)")
        for key, default in (("scale", 1.0), ("offset", 0.0)):
            v = spec.get(key, default)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or \
                    (key == "scale" and v == 0):
                raise LogFormatError(f"{where}: '{key}' must be a finite number{' other than 0' if key == 'scale' else ''}, "
                                     f"got {v!r}")
        angle = spec.get("angle")
        if angle is not None and (col not in ("gps_course", "gps_heading") or angle not in ANGLE_CONVENTIONS):
            raise LogFormatError(f"{where}: 'angle' = {angle!r}: only gps_course and gps_heading take "
                                 f"{', '.join(ANGLE_CONVENTIONS)}")
        out[col] = {"channel": spec["channel"], "unit": spec.get("unit"), "scale": float(spec.get("scale", 1.0)),
                    "offset": float(spec.get("offset", 0.0)), "angle": angle}
    missing = [c for c in REQUIRED if c != "t" and c not in out]
    if missing:
        raise LogFormatError(f"{path}: no table for the required column '{missing[0]}'")
    base = opts.get("time_base", "yaw_rate")
    if base not in out or base in GPS_COLUMNS:
        raise LogFormatError(f"{path}: [options] time_base = {base!r}: must be a mapped column that is not GPS")
    return {"time_base": base, "columns": out, "source": str(path)}


def read_mdf(path, channel_map) -> DriveLog:
    """A drive log from an MDF4 file and a channel map (a path or :func:`load_channel_map`'s result)."""
    from asammdf import MDF

    cmap = channel_map if isinstance(channel_map, dict) else load_channel_map(channel_map)
    path = Path(path)
    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many kinds for a file that is not MDF
        raise LogFormatError(f"{path}: not a readable MDF file ({type(exc).__name__}: {exc})") from None
    try:
        sigs = {}
        for col, spec in cmap["columns"].items():
            try:
                sig = mdf.get(spec["channel"])
            except Exception:
                raise LogFormatError(f"{path}: no channel '{spec['channel']}' (mapped to '{col}' in "
                                     f"{cmap['source']})") from None
            unit = (sig.unit or "").strip()
            if spec["unit"] is not None and unit and unit != spec["unit"]:
                raise LogFormatError(f"{path}: channel '{spec['channel']}' is in '{unit}', the channel map "
                                     f"({cmap['source']}) says '{spec['unit']}'")
            try:
                values = np.asarray(sig.samples, dtype=float)
            except (TypeError, ValueError):
                raise LogFormatError(f"{path}: channel '{spec['channel']}' is not numeric") from None
            sigs[col] = (np.asarray(sig.timestamps, float), values, spec)
    finally:
        mdf.close()
    t, base_vals, _ = sigs[cmap["time_base"]]
    _check_time(t, path, cmap["columns"][cmap["time_base"]]["channel"])
    cols = {"t": t}
    for col, (ts, v, spec) in sigs.items():
        v = v * spec["scale"] + spec["offset"]
        ch = spec["channel"]
        if col in GPS_COLUMNS:
            _check_time(ts, path, ch)
            rows, inside, _ = place_on_rows(t, ts, f"{path}: channel '{ch}'")
            vals = v[inside]
            if spec["angle"]:
                vals = yaw_sense(vals)
            out = np.full(len(t), math.nan)
            out[rows] = vals
        elif col == cmap["time_base"]:
            out = v
        else:
            _check_time(ts, path, ch)
            ok = np.isfinite(v)
            out = np.interp(t, ts[ok], v[ok]) if ok.any() else np.full(len(t), math.nan)
            out[(t < ts[0]) | (t > ts[-1])] = math.nan  # no extrapolation
        if col in REQUIRED:
            bad = np.flatnonzero(~np.isfinite(out))
            if col != "gps_course" and len(bad):
                raise LogFormatError(f"{path}: channel '{ch}' ('{col}'): no finite value at record {int(bad[0])} "
                                     f"(t = {float(t[bad[0]])!r}) of the time base")
        cols[col] = out
    log = DriveLog(cols, str(path))
    check_ranges(log)
    return log


def _check_time(ts: np.ndarray, path, channel: str) -> None:
    if len(ts) == 0:
        raise LogFormatError(f"{path}: channel '{channel}' has no samples")
    bad = np.flatnonzero(~(np.diff(ts) > 0))
    if len(bad) or not np.all(np.isfinite(ts)):
        i = int(bad[0]) + 1 if len(bad) else int(np.flatnonzero(~np.isfinite(ts))[0])
        raise LogFormatError(f"{path}: channel '{channel}': timestamp of record {i} ({float(ts[i])!r}) is not after "
                             f"the previous one; time must be strictly increasing")
