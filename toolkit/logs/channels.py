"""Logs recorded by other tools to the drive-log schema, through a channel map: ASAM MDF4 (asammdf),
MATLAB ``.mat`` (scipy.io; v7.3 files through h5py), CSV tables with their own column names, CAN traces
(BLF, ASC; python-can) with the car's DBC (cantools; :mod:`toolkit.logs.cantrace`): a channel is then a DBC
signal, ``SIGNAL`` or ``MESSAGE.SIGNAL``, and ``[options] dbc`` (or ``evstab convert --dbc``) names the DBC;
and ROS 2 bags (MCAP; :mod:`toolkit.logs.mcaplog`): a channel is ``TOPIC.FIELD``, ``[options] stamps`` says
whether a sample's time is its header stamp (``"header"``, the default) or its log time (``"log"``).

The channel map is a small TOML file, one table per schema column (``t`` excepted) or truth column::

    [meta]
    source = "who recorded it, where the conventions come from"

    [options]
    time_base = "yaw_rate"      # the column whose samples are the rows
    sample_rate = 200.0         # [Hz] files without a time vector (.mat, CSV): the rows' rate
    # time = "INS_time_sec"     # ... or the channel holding each row's time
    # time_scale = 1e-3         # its unit in s (1e-3 for ms, 1e-9 for ns)

    [speed]
    channels = ["VelRL", "VelRR"]   # several channels: their mean (wheel speeds of the rear axle)
    unit = "km/h"                   # the unit as logged: converted to the schema's (here m/s)

    [steer]
    channel = "SW_pos"
    unit = "deg"
    ratio = 13.5                    # a hand-wheel angle: divided by the steering ratio

    [ay]
    channel = "LatAcc"
    unit = "m/s^2"
    sign = -1                       # a right-positive sensor (ISO 8855 is left-positive)

    [gps_course]
    channel = "gnss_cog"
    unit = "deg"
    angle = "cw-from-north-deg"     # a receiver's bearing: to the yaw sense in rad, continuous
    held = true                     # the file repeats each epoch until the next: one fix per change

Per column: ``channel`` (or ``channels``, averaged; or ``value``, a constant in the schema's unit for a
signal the file does not have), ``unit`` as logged, ``scale`` and ``offset``
(``schema = sign * scale * logged / ratio + offset``; ``scale`` defaults to the factor of ``unit``
to the schema's unit, so ``unit = "deg"`` on a rad column converts), ``sign`` (+1 or -1),
``ratio`` (``steer`` only), ``angle``, ``held``; ``frame = "FRD"`` for a body signal logged
forward-right-down (:data:`FRD_FLIPPED` change sign); ``velocity = [X, Y]`` with ``frame = "ENU"`` or
``"NED"`` for ``gps_course`` or ``gps_speed`` from a receiver's horizontal velocity
(:func:`horizontal_velocity`); ``fix_status`` (GPS columns) for the receiver's status channel, a sample
counting where the latest status is >= 0 (:func:`fix_mask`). A unit that cannot be converted to the column's
(``deg`` for a speed) is refused, as is an unknown unit without a ``scale``. Truth columns
(``beta_true``, ``vx_true``, ``vy_true``, ``yaw_rate_true``, ...) are mapped the same way; where
``vx_true`` and ``vy_true`` are mapped and ``beta_true`` is not, ``beta_true = atan2(vy, vx)``.

Alignment: the rows are the time base's samples, less those outside the span every required channel covers
(:func:`required_span`: channels at several rates start and stop apart; the log's notes say what was
dropped). Other continuous channels are interpolated linearly onto them, never extrapolated (NaN outside an
optional channel's span; a gap in a required one is an error). GPS columns (``gps_*``) are placed, not interpolated: each sample on the first row at or
after its time (:func:`toolkit.logs.drivelog.place_on_rows`), so no fix is invented between real ones. A log
without ``gps_course`` is a reference log: ``evstab emulate`` adds a receiver's course to it.

CSV tables: the delimiter is found from the header; a file whose every row is one quoted field (a
ROS-bag dump) is read inside the quotes; a header name that repeats (``x``, ``y``, ``z`` after a
group column with no values) is qualified by the group, ``acc_body_hr.x``, and a name that still
repeats gets ``#2``, ``#3`` in order.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
from pathlib import Path

import numpy as np

from .drivelog import CAN_SUFFIXES, MCAP_SUFFIXES, REQUIRED, SCHEMA, TRUTH_COLUMNS, DriveLog, LogFormatError, check_ranges, place_on_rows, read_log_csv, read_toml

COLUMNS = tuple(c for c, _, _ in SCHEMA if c != "t")
MAPPABLE = COLUMNS + TRUTH_COLUMNS
GPS_COLUMNS = ("gps_course", "gps_speed", "gps_hdop", "gps_sats", "gps_heading")
ANGLE_CONVENTIONS = ("cw-from-north-deg",)
_KEYS = {"channel", "channels", "value", "unit", "scale", "offset", "sign", "ratio", "angle", "held", "frame", "velocity",
         "fix_status"}
_OPTIONS = {"time_base", "sample_rate", "time", "time_scale", "dbc", "stamps"}
FRD_FLIPPED = ("ay", "yaw_rate", "steer", "yaw_moment", "vy_true", "yaw_rate_true", "beta_true")
"""Columns along y or about z: their sign changes from a forward-right-down body frame to ISO 8855's
forward-left-up."""
FRD_KEPT = ("ax", "roll_rate", "vx_true", "roll_true")
"""Columns along or about x: the same in both body frames."""
EARTH_FRAMES = ("ENU", "NED")
_TRUTH_UNITS = {"beta_true": "rad", "yaw_rate_true": "rad/s", "yaw_true": "rad", "vx_true": "m/s", "vy_true": "m/s",
                "roll_true": "rad"}
SCHEMA_UNITS = {**{c: u for c, u, _ in SCHEMA}, **_TRUTH_UNITS}
"""The unit of every column a channel map can fill."""
UNITS = {
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180.0), "°": ("rad", math.pi / 180.0),
    "rad/s": ("rad/s", 1.0), "deg/s": ("rad/s", math.pi / 180.0), "°/s": ("rad/s", math.pi / 180.0),
    "rpm": ("rad/s", 2.0 * math.pi / 60.0),
    "m/s": ("m/s", 1.0), "km/h": ("m/s", 1.0 / 3.6), "mph": ("m/s", 0.44704), "kn": ("m/s", 1852.0 / 3600.0),
    "m/s^2": ("m/s^2", 1.0), "m/s2": ("m/s^2", 1.0), "g": ("m/s^2", 9.80665),
    "N m": ("N m", 1.0), "Nm": ("N m", 1.0), "-": ("-", 1.0), "": ("-", 1.0),
}
"""Units a channel may be logged in: the schema unit each converts to and the factor."""


def load_channel_map(path) -> dict:
    """Read and check a channel map (see the module docstring); errors name the file and the key."""
    path = Path(path)
    doc = read_toml(path)
    meta = doc.pop("meta", {})
    if not isinstance(meta, dict):
        raise LogFormatError(f"{path}: [meta] must be a table")
    opts = doc.pop("options", {})
    unknown_opts = set(opts) - _OPTIONS
    if unknown_opts:
        raise LogFormatError(f"{path}: [options]: unknown key '{sorted(unknown_opts)[0]}'; known: "
                             f"{', '.join(sorted(_OPTIONS))}")
    out = {}
    for col, spec in doc.items():
        out[col] = _column_spec(path, col, spec)
    missing = [c for c in REQUIRED if c not in ("t", "gps_course") and c not in out]
    if missing:
        raise LogFormatError(f"{path}: no table for the required column '{missing[0]}'")
    base = opts.get("time_base", "yaw_rate")
    if base not in out or base in GPS_COLUMNS or out[base]["value"] is not None:
        raise LogFormatError(f"{path}: [options] time_base = {base!r}: must be a mapped column that is not GPS")
    rate = opts.get("sample_rate")
    if rate is not None and (isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate)
                             or rate <= 0):
        raise LogFormatError(f"{path}: [options] sample_rate = {rate!r}: expected a rate in Hz above 0")
    tch = opts.get("time")
    if tch is not None and (not isinstance(tch, str) or not tch):
        raise LogFormatError(f"{path}: [options] time = {tch!r}: expected a channel name")
    if tch is not None and rate is not None:
        raise LogFormatError(f"{path}: [options]: give 'time' (a channel) or 'sample_rate', not both")
    tscale = opts.get("time_scale", 1.0)
    if isinstance(tscale, bool) or not isinstance(tscale, (int, float)) or not (math.isfinite(tscale) and tscale > 0):
        raise LogFormatError(f"{path}: [options] time_scale = {tscale!r}: expected the time channel's unit in s (> 0)")
    dbc = opts.get("dbc")
    if dbc is not None and (not isinstance(dbc, str) or not dbc):
        raise LogFormatError(f"{path}: [options] dbc = {dbc!r}: expected the path of the CAN trace's DBC file")
    from .mcaplog import STAMPS
    stamps = opts.get("stamps", "header")
    if stamps not in STAMPS:
        raise LogFormatError(f"{path}: [options] stamps = {stamps!r}: expected \"header\" (an MCAP message's "
                             f"header.stamp) or \"log\" (its log time)")
    return {"stamps": stamps, "time_base": base, "columns": out, "source": str(path), "sample_rate": None if rate is None else
            float(rate), "time": tch, "time_scale": float(tscale), "meta": dict(meta),
            "dbc": None if dbc is None else path.parent / dbc}


def _number(where, key, v, default, nonzero=False):
    v = default if v is None else v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (nonzero and v == 0):
        raise LogFormatError(f"{where}: '{key}' must be a finite number{' other than 0' if nonzero else ''}, got {v!r}")
    return float(v)


def _column_spec(path, col, spec) -> dict:
    where = f"{path}: [{col}]"
    if col not in MAPPABLE:
        raise LogFormatError(f"{where}: unknown schema column; known: {', '.join(MAPPABLE)}")
    if not isinstance(spec, dict):
        raise LogFormatError(f"{where}: expected a table with 'channel' (and 'unit', 'scale', 'offset')")
    bad = set(spec) - _KEYS
    if bad:
        raise LogFormatError(f"{where}: unknown key '{sorted(bad)[0]}'; known: {', '.join(sorted(_KEYS))}")
    if "value" in spec:  # a signal the file does not have, at a known constant value (a log without steering)
        if set(spec) - {"value", "unit"}:
            raise LogFormatError(f"{where}: 'value' (a constant in the schema's unit) takes no other key but 'unit'")
        if col in GPS_COLUMNS or col.endswith("_true"):
            raise LogFormatError(f"{where}: 'value' is for measured signals, not GPS or truth columns")
        return {"channel": None, "channels": [], "value": _number(where, "value", spec["value"], 0.0), "unit": None,
                "scale": 1.0, "offset": 0.0, "angle": None, "held": False, "velocity": None, "fix_status": None}
    fix_status = spec.get("fix_status")
    if fix_status is not None and (col not in GPS_COLUMNS or not isinstance(fix_status, str) or not fix_status):
        raise LogFormatError(f"{where}: 'fix_status' = {fix_status!r}: a GPS column's receiver status channel "
                             f"(a fix where it is >= 0, sensor_msgs/NavSatStatus)")
    if "velocity" in spec:
        return _velocity_spec(where, col, spec, fix_status)
    if "channel" not in spec and "channels" not in spec:
        raise LogFormatError(f"{where}: missing key 'channel' (the channel name in the file; or 'channels', a list "
                             f"of channels averaged)")
    if "channel" in spec and "channels" in spec:
        raise LogFormatError(f"{where}: give 'channel' or 'channels', not both")
    names = [spec["channel"]] if "channel" in spec else spec["channels"]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise LogFormatError(f"{where}: 'channel' must be a name and 'channels' a list of names")
    unit = spec.get("unit")
    if unit is not None and not isinstance(unit, str):
        raise LogFormatError(f"{where}: 'unit' must be a string, got {unit!r}")
    frame = spec.get("frame")
    if frame is not None and (frame not in ("FLU", "FRD") or col not in FRD_FLIPPED + FRD_KEPT):
        raise LogFormatError(f"{where}: 'frame' = {frame!r}: body axes \"FLU\" (ISO 8855) or \"FRD\", for "
                             f"{', '.join(FRD_FLIPPED + FRD_KEPT)}; a receiver's velocity takes \"ENU\" or "
                             f"\"NED\" with 'velocity'")
    angle = spec.get("angle")
    if angle is not None and (col not in ("gps_course", "gps_heading") or angle not in ANGLE_CONVENTIONS):
        raise LogFormatError(f"{where}: 'angle' = {angle!r}: only gps_course and gps_heading take "
                             f"{', '.join(ANGLE_CONVENTIONS)}")
    if angle is not None and unit not in (None, "deg", "°"):
        raise LogFormatError(f"{where}: 'angle' = {angle!r} is a bearing in degrees; the unit is {unit!r}")
    target = SCHEMA_UNITS[col]
    if "scale" in spec or angle is not None:
        scale = _number(where, "scale", spec.get("scale"), 1.0, nonzero=True)
    elif unit is None:
        scale = 1.0
    else:
        if unit not in UNITS:
            raise LogFormatError(f"{where}: unit {unit!r} is not one evstab converts ({', '.join(k for k in UNITS if k)}"
                                 f"); give 'scale' (schema {target} per logged unit)")
        dim, scale = UNITS[unit]
        if dim != target:
            raise LogFormatError(f"{where}: unit {unit!r} is {dim}, column '{col}' is in {target}")
    sign = _number(where, "sign", spec.get("sign"), 1.0)
    if sign not in (1.0, -1.0):
        raise LogFormatError(f"{where}: 'sign' must be 1 or -1, got {spec.get('sign')!r}")
    ratio = spec.get("ratio")
    if ratio is not None and col != "steer":
        raise LogFormatError(f"{where}: 'ratio' (hand-wheel to road-wheel angle) is for 'steer' only")
    ratio = _number(where, "ratio", ratio, 1.0)
    if not 1.0 <= ratio <= 100.0:
        raise LogFormatError(f"{where}: 'ratio' = {ratio!r}: a steering ratio is between 1 and 100")
    held = spec.get("held", False)
    if not isinstance(held, bool):
        raise LogFormatError(f"{where}: 'held' must be true or false, got {held!r}")
    if held and col not in GPS_COLUMNS:
        raise LogFormatError(f"{where}: 'held' is for GPS columns (one fix per change of value)")
    if frame == "FRD" and col in FRD_FLIPPED:
        sign = -sign
    return {"channel": names[0], "channels": names, "value": None, "unit": unit, "scale": scale * sign / ratio,
            "offset": _number(where, "offset", spec.get("offset"), 0.0), "angle": angle, "held": held,
            "velocity": None, "fix_status": fix_status}


def _velocity_spec(where, col, spec, fix_status) -> dict:
    """``velocity = [X, Y]`` with ``frame = "ENU"`` or ``"NED"``: the course (yaw sense, rad) or the ground
    speed of a receiver's horizontal velocity."""
    if col not in ("gps_course", "gps_speed"):
        raise LogFormatError(f"{where}: 'velocity' (a receiver's horizontal velocity) gives gps_course or gps_speed")
    extra = set(spec) - {"velocity", "frame", "unit", "held", "fix_status"}
    if extra:
        raise LogFormatError(f"{where}: 'velocity' takes 'frame', 'unit', 'held' and 'fix_status', not "
                             f"'{sorted(extra)[0]}'")
    names = spec["velocity"]
    if not isinstance(names, list) or len(names) != 2 or not all(isinstance(n, str) and n for n in names):
        raise LogFormatError(f"{where}: 'velocity' must be two channel names, the horizontal velocity's x and y "
                             f"components in 'frame'")
    frame = spec.get("frame")
    if frame not in EARTH_FRAMES:
        raise LogFormatError(f"{where}: 'velocity' needs 'frame' = \"ENU\" (x east, y north: REP 103) or \"NED\" "
                             f"(x north, y east), got {frame!r}")
    unit = spec.get("unit", "m/s")
    if not isinstance(unit, str) or UNITS.get(unit, ("",))[0] != "m/s":
        raise LogFormatError(f"{where}: 'unit' = {unit!r}: the velocity's unit, a speed ({', '.join(k for k, (d, _) in UNITS.items() if d == 'm/s')})")
    held = spec.get("held", False)
    if not isinstance(held, bool):
        raise LogFormatError(f"{where}: 'held' must be true or false, got {held!r}")
    return {"channel": names[0], "channels": list(names), "value": None, "unit": None,
            "scale": UNITS[unit][1] if col == "gps_speed" else 1.0, "offset": 0.0, "angle": None, "held": held,
            "velocity": frame, "fix_status": fix_status}


def horizontal_velocity(col: str, frame: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The course in the yaw sense [rad] (0 east, counter-clockwise; unwrapped over the finite values) or the
    ground speed of a horizontal velocity ``(x, y)`` in ``frame`` (ENU: x east, y north; NED: x north, y east).
    No velocity has no course: NaN where both components are 0."""
    east, north = (x, y) if frame == "ENU" else (y, x)
    if col == "gps_speed":
        return np.hypot(east, north)
    a = np.arctan2(north, east)
    a[(east == 0) & (north == 0)] = np.nan
    ok = np.isfinite(a)
    a[ok] = np.unwrap(a[ok])
    return a


# --- sources: name -> (timestamps or None, values, unit or None) ------------------------------------------------

def _mdf_channels(path: Path, names) -> dict:
    from asammdf import MDF
    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many kinds for a file that is not MDF
        raise LogFormatError(f"{path}: not a readable MDF file ({type(exc).__name__}: {exc})") from None
    out: dict[str, tuple | None] = {}
    try:
        for name in names:
            try:
                sig = mdf.get(name)
            except Exception:
                out[name] = None
                continue
            try:
                values = np.asarray(sig.samples, dtype=float)
            except (TypeError, ValueError):
                raise LogFormatError(f"{path}: channel '{name}' is not numeric") from None
            out[name] = (np.asarray(sig.timestamps, float), values, (sig.unit or "").strip() or None)
    finally:
        mdf.close()
    return out


def _mat_channels(path: Path, names) -> dict:
    import scipy.io
    try:
        raw = scipy.io.loadmat(str(path), squeeze_me=True)
        data = {k: v for k, v in raw.items() if not k.startswith("__")}
    except NotImplementedError:  # MATLAB v7.3: HDF5
        import h5py
        with h5py.File(str(path), "r") as fh:
            data = {k: np.asarray(fh[k]) for k in fh.keys() if isinstance(fh[k], h5py.Dataset)}
    except Exception as exc:
        raise LogFormatError(f"{path}: not a readable MATLAB file ({type(exc).__name__}: {exc})") from None
    out: dict[str, tuple | None] = {}
    for name in names:
        if name not in data:
            out[name] = None
            continue
        try:
            v = np.asarray(data[name], float).ravel()
        except (TypeError, ValueError):
            raise LogFormatError(f"{path}: variable '{name}' is not numeric") from None
        out[name] = (None, v, None)
    return out


def table_header(names: list[str], first_row: list[str]) -> list[str]:
    """Qualified names of a CSV header (see the module docstring): ``x``, ``y`` and ``z`` after a group
    column (one with no value in the first row) become ``group.x``, ...; a name still repeated gets
    ``#2``, ``#3`` in order."""
    out: list[str] = []
    group: str | None = None
    seen: dict[str, int] = {}
    for k, raw in enumerate(names):
        n = raw.strip()
        value = first_row[k].strip() if k < len(first_row) else ""
        if n in ("x", "y", "z"):
            name = f"{group}.{n}" if group is not None else n
        else:
            name = n
            if value == "":
                group = n
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name}#{seen[name]}")
    return out


def _csv_channels(path: Path, names) -> dict:
    try:
        raw = path.read_bytes()
        if path.suffix.lower() == ".gz":
            raw = gzip.decompress(raw)
        text = raw.decode("utf-8-sig")
    except OSError as exc:
        raise LogFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (EOFError, UnicodeDecodeError) as exc:
        raise LogFormatError(f"{path}: not a readable text file ({exc})") from None
    lines = text.splitlines()
    if len(lines) < 2:
        raise LogFormatError(f"{path}: expected a header row and data rows")
    try:
        dialect = csv.Sniffer().sniff(lines[0], delimiters=",;\t")
        delim = dialect.delimiter
    except csv.Error:
        delim = ","
    header = next(csv.reader([lines[0]], delimiter=delim))
    rows = list(csv.reader(io.StringIO("\n".join(lines[1:])), delimiter=delim))
    rows = [r for r in rows if r and any(x.strip() for x in r)]
    if rows and len(header) > 1 and all(len(r) == 1 for r in rows[:50]):  # every row one quoted string
        rows = [next(csv.reader([r[0]], delimiter=delim)) if r else [] for r in rows]
    bad = next((k for k, r in enumerate(rows) if len(r) != len(header)), None)
    if bad is not None:
        raise LogFormatError(f"{path}: row {bad + 2}: {len(rows[bad])} fields, expected {len(header)} "
                             f"(truncated or malformed line)")
    qualified = table_header(header, rows[0] if rows else [])
    index = {n: k for k, n in enumerate(qualified)}
    out: dict[str, tuple | None] = {}
    for name in names:
        if name not in index:
            out[name] = None
            continue
        k = index[name]
        v = np.empty(len(rows))
        for i, r in enumerate(rows):
            try:
                v[i] = float(r[k]) if r[k].strip() else math.nan
            except ValueError:
                raise LogFormatError(f"{path}: row {i + 2}, column '{name}': {r[k]!r} is not a number") from None
        out[name] = (None, v, None)
    return out


def source_kind(path) -> str:
    """``mdf``, ``mat``, ``can`` (a BLF or ASC trace), ``mcap`` (a ROS 2 bag) or ``csv`` by the file name."""
    name = str(path).lower()
    if name.endswith((".mf4", ".mdf")):
        return "mdf"
    if name.endswith(".mat"):
        return "mat"
    if name.endswith(CAN_SUFFIXES):
        return "can"
    if name.endswith(MCAP_SUFFIXES):
        return "mcap"
    return "csv"


def read_mapped(path, channel_map) -> DriveLog:
    """A drive log (possibly a reference log without ``gps_course``) from an MDF4, MATLAB or CSV file, or a CAN
    trace (BLF, ASC) decoded with the map's DBC (:mod:`toolkit.logs.cantrace`), and a channel map (a path or
    :func:`load_channel_map`'s result)."""
    cmap = channel_map if isinstance(channel_map, dict) else load_channel_map(channel_map)
    path = Path(path)
    if not path.exists():
        raise LogFormatError(f"{path}: no such file")
    kind = source_kind(path)
    wanted = sorted({n for spec in cmap["columns"].values() for n in spec["channels"]} |
                    {spec["fix_status"] for spec in cmap["columns"].values() if spec["fix_status"]} |
                    ({cmap["time"]} if cmap["time"] else set()))
    notes: tuple | list = ()
    if kind == "can":
        from .cantrace import can_channels
        got, notes = can_channels(path, wanted, cmap.get("dbc"))
    elif kind == "mcap":
        from .mcaplog import mcap_channels
        got = mcap_channels(path, wanted, cmap.get("stamps", "header"))
    else:
        got = {"mdf": _mdf_channels, "mat": _mat_channels, "csv": _csv_channels}[kind](path, wanted)
    for col, spec in cmap["columns"].items():
        for n in spec["channels"]:
            if got.get(n) is None:
                raise LogFormatError(f"{path}: no channel '{n}' (mapped to '{col}' in {cmap['source']})")
            unit = got[n][2]
            if spec["unit"] is not None and unit and unit != spec["unit"]:
                raise LogFormatError(f"{path}: channel '{n}' is in '{unit}', the channel map ({cmap['source']}) "
                                     f"says '{spec['unit']}'")
    for col, spec in cmap["columns"].items():
        if spec["fix_status"] and got.get(spec["fix_status"]) is None:
            raise LogFormatError(f"{path}: no channel '{spec['fix_status']}' (the fix status of '{col}' in "
                                 f"{cmap['source']})")
    if cmap["time"] and got.get(cmap["time"]) is None:
        raise LogFormatError(f"{path}: no channel '{cmap['time']}' ([options] time in {cmap['source']})")

    def stamps(name):
        ts, v, _ = got[name]
        if ts is not None:
            return ts
        if cmap["time"]:
            t = got[cmap["time"]][1] * cmap["time_scale"]
        elif cmap["sample_rate"]:
            t = np.arange(len(v)) / cmap["sample_rate"]
        else:
            raise LogFormatError(f"{path}: a {kind.upper()} file has no time stamps: give [options] sample_rate "
                                 f"(Hz) or time (a channel) in {cmap['source']}")
        if len(t) != len(v):
            raise LogFormatError(f"{path}: channel '{name}' has {len(v)} samples, the time base {len(t)}")
        return t

    sigs = {}
    for col, spec in cmap["columns"].items():
        if spec["value"] is not None:
            continue
        ts = [stamps(n) for n in spec["channels"]]
        series = [got[n][1] for n in spec["channels"]]
        if len(series) > 1 and any(len(x) != len(series[0]) or not np.array_equal(t, ts[0])
                                   for x, t in zip(series, ts)):
            raise LogFormatError(f"{path}: the channels of '{col}' ({', '.join(spec['channels'])}) are not sampled "
                                 f"together; {'a velocity' if spec['velocity'] else 'averaging them'} needs one "
                                 f"time base")
        if spec["velocity"]:
            sigs[col] = (ts[0], horizontal_velocity(col, spec["velocity"], *series), spec)
        else:
            sigs[col] = (ts[0], np.mean(series, axis=0) if len(series) > 1 else series[0], spec)
    t, _, _ = sigs[cmap["time_base"]]
    _check_time(t, path, cmap["columns"][cmap["time_base"]]["channel"])
    span, trimmed = required_span(t, {col: sig for col, sig in sigs.items() if col in REQUIRED and col not in
                                      GPS_COLUMNS and col != cmap["time_base"]}, path)
    notes = tuple(notes) + trimmed
    t = t[span]
    cols = {"t": t - t[0] if kind != "mdf" and cmap["time"] else t}
    for col, (ts, v, spec) in sigs.items():
        ch = spec["channel"]
        if col in GPS_COLUMNS:
            _check_time(ts, path, ch)
            keep = np.isfinite(v)
            if spec["held"]:  # one fix per change of value (the first sample of each epoch)
                keep &= np.concatenate([[True], np.diff(v) != 0])
            if spec["fix_status"]:  # the receiver's latest status at or before the sample: a fix where >= 0
                st_t, st_v = stamps(spec["fix_status"]), got[spec["fix_status"]][1]
                known = np.isfinite(st_v)  # a table's rows without a status message are empty
                keep &= fix_mask(ts, st_t[known], st_v[known])
            ts_k, v_k = ts[keep], v[keep]
            rows, inside, _ = place_on_rows(t, ts_k, f"{path}: channel '{ch}'")
            vals = v_k[inside]
            if spec["angle"]:
                from .nmea import yaw_sense
                vals = yaw_sense(vals * spec["scale"])
                vals = vals + spec["offset"]
            else:
                vals = vals * spec["scale"] + spec["offset"]
            out = np.full(len(t), math.nan)
            out[rows] = vals
        else:
            v = v * spec["scale"] + spec["offset"]
            if col == cmap["time_base"]:
                out = v[span]
            else:
                _check_time(ts, path, ch)
                ok = np.isfinite(v)
                out = np.interp(t, ts[ok], v[ok]) if ok.any() else np.full(len(t), math.nan)
                out[(t < ts[0]) | (t > ts[-1])] = math.nan  # no extrapolation
        if col in REQUIRED and col != "gps_course":
            bad = np.flatnonzero(~np.isfinite(out))
            if len(bad):
                raise LogFormatError(f"{path}: channel '{ch}' ('{col}'): no finite value at record {int(bad[0])} "
                                     f"(t = {float(t[bad[0]])!r}) of the time base")
        cols[col] = out
    for col, spec in cmap["columns"].items():
        if spec["value"] is not None:
            cols[col] = np.full(len(t), spec["value"])
    if "gps_course" not in cols:
        cols["gps_course"] = np.full(len(t), math.nan)
    if "beta_true" not in cols and "vx_true" in cols and "vy_true" in cols:
        cols["beta_true"] = np.arctan2(cols["vy_true"], cols["vx_true"])
    log = DriveLog(cols, str(path), tuple(notes))
    check_ranges(log)
    return log


def required_span(t: np.ndarray, sigs: dict, path) -> tuple[slice, tuple]:
    """The rows of the time base ``t`` inside the span every required channel (``col -> (times, values,
    spec)``) has finite samples over, and a note per end trimmed: channels logged at several rates start and
    stop a few samples apart, and a required column is never extrapolated. A gap inside the span stays an
    error (:func:`read_mapped`)."""
    lo, hi = -math.inf, math.inf
    first = last = ("", "")  # (column, channel) of the latest start and the earliest end
    for col, (ts, v, spec) in sigs.items():
        ok = np.flatnonzero(np.isfinite(v))
        if not len(ok):
            continue
        if ts[ok[0]] > lo:
            lo, first = float(ts[ok[0]]), (col, spec["channel"])
        if ts[ok[-1]] < hi:
            hi, last = float(ts[ok[-1]]), (col, spec["channel"])
    i, j = int(np.searchsorted(t, lo, side="left")), int(np.searchsorted(t, hi, side="right"))
    if i >= j:
        raise LogFormatError(f"{path}: the required channels have no common span on the time base's rows "
                             f"('{first[1]}' ({first[0]}) starts at {lo!r} s, '{last[1]}' ({last[0]}) ends at "
                             f"{hi!r} s)")
    notes = []
    if i:
        notes.append(f"rows: the first {i} (before t = {lo:.6g} s) dropped, before the first sample of "
                     f"'{first[1]}' ({first[0]})")
    if j < len(t):
        notes.append(f"rows: the last {len(t) - j} (after t = {hi:.6g} s) dropped, after the last sample of "
                     f"'{last[1]}' ({last[0]})")
    return slice(i, j), tuple(notes)


def fix_mask(ts: np.ndarray, status_t: np.ndarray, status: np.ndarray) -> np.ndarray:
    """True at the times ``ts`` whose latest receiver status (``status`` at ``status_t``, at or before the
    time) is a fix: >= 0 in sensor_msgs/NavSatStatus (-1 no fix, 0 fix, 1 SBAS, 2 ground-based
    augmentation). A time before the first status has none."""
    j = np.searchsorted(status_t, ts, side="right") - 1
    ok = j >= 0
    out = np.zeros(len(ts), bool)
    out[ok] = status[j[ok]] >= 0
    return out


def _check_time(ts: np.ndarray, path, channel: str) -> None:
    if len(ts) == 0:
        raise LogFormatError(f"{path}: channel '{channel}' has no samples")
    bad = np.flatnonzero(~(np.diff(ts) > 0))
    if len(bad) or not np.all(np.isfinite(ts)):
        i = int(bad[0]) + 1 if len(bad) else int(np.flatnonzero(~np.isfinite(ts))[0])
        raise LogFormatError(f"{path}: channel '{channel}': timestamp of record {i} ({float(ts[i])!r}) is not after "
                             f"the previous one; time must be strictly increasing")


def read_log(path: str | Path, columns: tuple[str, ...] | None = None, channel_map=None) -> DriveLog:
    """A drive log from ``.csv`` or ``.csv.gz`` in the schema, or, through a channel map (:func:`read_mapped`),
    from an MDF4 file (``.mf4``/``.mdf``), a MATLAB file (``.mat``), a CSV table with its own column names, a
    CAN trace (``.blf``, ``.asc``) or a ROS 2 bag (``.mcap``); ``columns`` keeps those and the required ones."""
    name = str(path).lower()
    if channel_map is None and name.endswith((".mf4", ".mdf", ".mat") + CAN_SUFFIXES + MCAP_SUFFIXES):
        kind = "an MDF" if name.endswith((".mf4", ".mdf")) else "a CAN trace" if name.endswith(CAN_SUFFIXES) \
            else "an MCAP" if name.endswith(MCAP_SUFFIXES) else "a MATLAB"
        raise LogFormatError(f"{path}: {kind} log needs a channel map (--channel-map MAP.toml) that names "
                             f"the channel of each schema column")
    if channel_map is not None:
        log = read_mapped(path, channel_map)
        if columns is not None:
            keep = set(REQUIRED) | set(columns)
            log = DriveLog({k: v for k, v in log.columns.items() if k in keep}, log.source, log.notes)
        return log
    return read_log_csv(path, columns)
