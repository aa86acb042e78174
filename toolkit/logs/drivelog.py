"""The drive-log CSV (docs/formats.md): one writer and one reader for simulated and recorded runs.

The writer is atomic (temporary name in the target directory, renamed when
complete). The reader rejects a bad file with a :class:`LogFormatError` naming the
file, the row (1-based line number in the file, the header being line 1), the
column and what was expected.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evstab.plants.errors import EvstabError

SCHEMA = (
    ("t", "s", True), ("speed", "m/s", True), ("steer", "rad", True), ("yaw_moment", "N m", False),
    ("yaw_rate", "rad/s", True), ("ax", "m/s^2", False), ("ay", "m/s^2", False), ("roll_rate", "rad/s", False),
    ("wheel_speed_fl", "rad/s", False), ("wheel_speed_fr", "rad/s", False), ("wheel_speed_rl", "rad/s", False),
    ("wheel_speed_rr", "rad/s", False), ("gps_course", "rad", True), ("gps_speed", "m/s", False),
    ("gps_hdop", "-", False), ("gps_sats", "-", False), ("gps_heading", "rad", False),
)
"""(column, unit, required) of the drive-log schema, in the order the writer uses."""
REQUIRED = tuple(c for c, _, req in SCHEMA if req)
PLAUSIBLE = {
    "speed": (-30.0, 150.0), "steer": (-1.2, 1.2), "yaw_moment": (-1e5, 1e5), "yaw_rate": (-10.0, 10.0),
    "ax": (-100.0, 100.0), "ay": (-100.0, 100.0), "roll_rate": (-10.0, 10.0),
    "wheel_speed_fl": (-1000.0, 1000.0), "wheel_speed_fr": (-1000.0, 1000.0), "wheel_speed_rl": (-1000.0, 1000.0),
    "wheel_speed_rr": (-1000.0, 1000.0), "gps_speed": (0.0, 150.0), "gps_hdop": (0.0, 100.0), "gps_sats": (0.0, 255.0),
}
"""Physically possible range of each schema column (SI): 540 km/h, 69 deg of road-wheel angle,
573 deg/s, 10 g, 1000 rad/s wheel speed. A value outside is a unit or scaling error (km/h for
m/s, deg for rad), which the reader names instead of passing on."""
TRUTH_COLUMNS = ("beta_true", "yaw_rate_true", "yaw_true", "vx_true", "vy_true", "roll_true")


CAN_SUFFIXES = (".blf", ".asc")
"""CAN traces (python-can's BLF and ASC), read through a channel map and a DBC (:mod:`toolkit.logs.cantrace`)."""
MCAP_SUFFIXES = (".mcap",)
"""ROS 2 bags and other MCAP files, read through a channel map (:mod:`toolkit.logs.mcaplog`)."""


class LogFormatError(EvstabError, ValueError):
    """A drive log does not follow the schema; the message names file, row and column."""


@dataclass(frozen=True)
class DriveLog:
    """Columns of a drive log as float arrays (NaN = empty), plus where it came from."""

    columns: dict
    source: str
    notes: tuple = ()
    """What the reader noticed and the user should hear, one line each (a CAN trace's late frames)."""

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise LogFormatError(f"{self.source}: no column '{name}'") from None

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    def __len__(self) -> int:
        return len(self.columns["t"])

    def without_truth(self) -> "DriveLog":
        """The same log with every ``*_true`` column removed (what an estimator may see)."""
        return DriveLog({k: v for k, v in self.columns.items() if not k.endswith("_true")}, self.source)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: str | Path, write, mode: str = "w") -> None:
    """Call ``write(fileobj)`` on a temporary file next to ``path``; rename it to ``path`` when done."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".part", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; the result gets an ordinary file's mode
        with os.fdopen(fd, mode, newline=None if "b" in mode else "") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def read_toml(path, error=None) -> dict:
    """A TOML file's document; a file that cannot be read or is not TOML raises ``error`` (default
    :class:`LogFormatError`) naming the file."""
    import tomllib
    error = LogFormatError if error is None else error
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not a TOML file ({exc})") from None


def write_log_csv(path: str | Path, columns: dict) -> None:
    """Write a drive log: schema columns first (in schema order), then the rest; NaN as empty."""
    missing = [c for c in REQUIRED if c not in columns]
    if missing:
        raise LogFormatError(f"{path}: cannot write a drive log without column(s) {', '.join(missing)}")
    schema = [c for c, _, _ in SCHEMA]
    order = [c for c in schema if c in columns] + [c for c in columns if c not in schema]
    write_log_table(path, {c: columns[c] for c in order})


def write_log_table(path: str | Path, columns: dict) -> None:
    """Write a table of float columns as CSV (NaN as empty, shortest round-trip digits; integer and
    boolean columns as integers), atomically, in the given order (pyarrow's CSV writer)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    def arr(v):
        v = np.asarray(v)
        if v.dtype.kind in "iub":  # flags and counts stay integers (written as 0/1, much faster than floats)
            return pa.array(v.astype(np.int64) if v.dtype.kind == "b" else v)
        return pa.array(np.asarray(v, float), from_pandas=True)

    table = pa.table({c: arr(columns[c]) for c in columns})
    opts = pacsv.WriteOptions(include_header=False, quoting_style="none")

    def write(fh):
        fh.write((",".join(columns) + "\n").encode())
        pacsv.write_csv(table, fh, opts)

    atomic_write(path, write, mode="wb")


def _float(text: str, source: str, row: int, col: str, allow_empty: bool) -> float:
    s = text.strip()
    if s == "" or s.lower() == "nan":
        if allow_empty:
            return math.nan
        raise LogFormatError(f"{source}: row {row}, column '{col}': empty or NaN, expected a finite number")
    try:
        v = float(s)
    except ValueError:
        raise LogFormatError(f"{source}: row {row}, column '{col}': '{s[:40]}' is not a number") from None
    if math.isinf(v):
        raise LogFormatError(f"{source}: row {row}, column '{col}': {s} is not finite")
    if math.isnan(v) and not allow_empty:
        raise LogFormatError(f"{source}: row {row}, column '{col}': NaN, expected a finite number")
    return v


def read_log_csv(path: str | Path, columns: tuple[str, ...] | None = None,
                 required: tuple[str, ...] = REQUIRED) -> DriveLog:
    """Read and validate a drive-log CSV (see the module docstring for the errors).

    A fast path (pyarrow's CSV parser) reads well-formed files; anything it does not
    accept cleanly is re-read by the strict row-by-row parser, whose error names
    the row and column.
    ``columns`` restricts the result (and the fast parser's work) to those columns
    plus the required ones; other columns are then neither parsed nor checked.
    ``required``: the columns that must be there (default the schema's; an IMU log that
    is to be merged with a GNSS log has no ``gps_course`` yet).
    """
    keep = None if columns is None else tuple(dict.fromkeys(tuple(required) + tuple(columns)))
    log = _read_fast(Path(path), keep, tuple(required))
    if log is None:
        log = _read_strict(Path(path), tuple(required))
        if keep is not None:
            log = DriveLog({k: v for k, v in log.columns.items() if k in keep}, log.source, log.notes)
    check_ranges(log)
    return log


def place_on_rows(t: np.ndarray, t_samples: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """Rows of the time base ``t`` that slower samples (GPS fixes) land on: each on the first row at
    or after its time, so no sample is invented between real ones and none is used before it exists.

    Returns the rows, the mask of samples inside the log and counts (``placed``, ``before``,
    ``after``). Two samples on one row (the base slower than the samples) is a
    :class:`LogFormatError` naming the row.
    """
    tol = 1e-9 * max(1.0, float(np.max(np.abs(t))))  # timestamps written with rounding
    k = np.searchsorted(t, np.asarray(t_samples, float) - tol, side="left")
    inside = (t_samples >= t[0] - tol) & (k < len(t))
    rows = k[inside]
    if len(rows) != len(np.unique(rows)):
        dup = rows[np.flatnonzero(np.diff(rows) == 0)[0]]
        raise LogFormatError(f"{source}: two samples fall on row {int(dup) + 2} (t = {float(t[dup])!r}) of the time "
                             f"base; it must be sampled faster than them")
    counts = {"placed": int(inside.sum()), "before": int((t_samples < t[0] - tol).sum()),
              "after": int(((t_samples >= t[0] - tol) & (k >= len(t))).sum())}
    return rows, inside, counts


def check_ranges(log: DriveLog) -> None:
    """Raise :class:`LogFormatError` at the first value outside :data:`PLAUSIBLE` (row, column, range)."""
    for name, (lo, hi) in PLAUSIBLE.items():
        v = log.columns.get(name)
        if v is None:
            continue
        bad = np.flatnonzero(np.isfinite(v) & ((v < lo) | (v > hi)))
        if len(bad):
            unit = next(u for c, u, _ in SCHEMA if c == name)
            raise LogFormatError(f"{log.source}: row {int(bad[0]) + 2}, column '{name}': {float(v[bad[0]])!r} "
                                 f"is outside the possible range [{lo:g}, {hi:g}] {unit} (a unit or scaling "
                                 f"error?)")


UNIT_SLOPE_SE = 0.2
"""Standard error of the course-on-gyro slope above which a log cannot tell the gyro's unit from the
GPS course's (too little turning for the course noise): no verdict."""


def check_units(log: DriveLog) -> None:
    """Unit mistakes that the ranges of :data:`PLAUSIBLE` cannot see, found by consistency between
    columns; raises :class:`LogFormatError` with the column, the evidence and the likely unit.

    * ``yaw_rate`` against ``gps_course``: between consecutive fixes the course changes by the
      integrated yaw rate plus the sideslip's change. The least-squares slope of the course
      increments on the integrated yaw-rate increments is 1 for ISO 8855 units; 1/57.3 means the
      yaw rate is in deg/s, 57.3 that the course is in degrees, -1 that the course is a compass
      bearing (clockwise from north). Judged only when the slope's standard error (from the
      residuals) is below :data:`UNIT_SLOPE_SE`.
    * ``speed`` against ``gps_speed`` (above 3 m/s): a median ratio of 3.6 (or 1/3.6) means one of
      them is in km/h, 2.24 in mph.
    """
    t, r = log["t"], log["yaw_rate"]
    c = log["gps_course"]
    k = np.flatnonzero(np.isfinite(c))
    if len(k) >= 5:
        psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(t))])
        dpsi = np.diff(psi[k])
        dc = np.diff(c[k])
        dc_wrapped = (dc + np.pi) % (2 * np.pi) - np.pi
        def fit(y):
            """Least-squares slope of ``y`` on ``dpsi`` and its standard error."""
            ss = float(np.dot(dpsi, dpsi))
            if ss <= 0:
                return 0.0, np.inf
            b = float(np.dot(dpsi, y) / ss)
            return b, float(np.sqrt(np.sum((y - b * dpsi) ** 2) / max(len(y) - 1, 1) / ss))

        slope, se = fit(dc_wrapped)
        slope_raw, se_raw = fit(dc)  # a course in degrees: increments of degrees, not wrapped at pi
        evidence = (f"over {len(k)} fixes the GPS course changes {slope:.3g} times as much as the integrated "
                    f"yaw rate (1 expected)")
        if se < UNIT_SLOPE_SE and 1 / 100 < slope < 1 / 30:
            raise LogFormatError(f"{log.source}: column 'yaw_rate': {evidence}; the yaw rate looks like deg/s "
                                 "(ratio near 1/57.3), expected rad/s")
        if se_raw < UNIT_SLOPE_SE * abs(slope_raw) and 30 < abs(slope_raw) < 100:
            raise LogFormatError(f"{log.source}: column 'gps_course': over {len(k)} fixes the GPS course changes "
                                 f"{slope_raw:.3g} times as much as the integrated yaw rate (1 expected); it looks "
                                 "like degrees" + (" clockwise from north (a compass bearing)" if slope_raw < 0
                                                   else "") + ", expected rad, counter-clockwise (ISO 8855)")
        if se < UNIT_SLOPE_SE and -2.0 < slope < -0.5:
            raise LogFormatError(f"{log.source}: column 'gps_course': {evidence}; it turns the other way than the "
                                 "gyro: a compass bearing (clockwise from north), expected counter-clockwise from "
                                 "the x axis (ISO 8855; course = pi/2 - bearing)")
    if "gps_speed" in log:
        v, g = log["speed"], log["gps_speed"]
        ok = np.isfinite(v) & np.isfinite(g) & (g > 3.0) & (np.abs(v) > 0.1)
        if ok.sum() >= 5:
            ratio = float(np.median(v[ok] / g[ok]))
            for factor, unit in ((3.6, "km/h"), (2.237, "mph")):
                for col, rr in (("speed", ratio), ("gps_speed", 1.0 / ratio)):
                    if abs(rr / factor - 1.0) < 0.1:
                        raise LogFormatError(
                            f"{log.source}: column '{col}': the median of speed / gps_speed over {int(ok.sum())} rows "
                            f"is {ratio:.3g} (1 expected); '{col}' looks like {unit}, expected m/s")


def check_steer(log: DriveLog, wheelbase: float, understeer: float = 0.0) -> None:
    """A hand-wheel angle logged as ``steer`` (the road-wheel angle), found by consistency with the yaw rate:
    in cornering well inside the tyres' linear range the road-wheel angle is the steady-state one,
    ``(l / v + K v) r`` (wheelbase ``l``, understeer gradient ``K`` [rad per m/s^2],
    :attr:`plants.VehicleParams.understeer_gradient`). The least-squares slope of
    ``steer`` on it, over rows above 3 m/s with ``|r|`` above 0.02 rad/s and ``|a_y|`` (``v r`` where the log
    has no ``ay``) below 3 m/s^2, is about 1 (a wrong nominal model moves it by tens of %); from 5 to 40 the
    column holds the hand-wheel angle (steering ratios are 10-20). Judged on 200 such rows or more, and only
    when the slope's standard error is below a tenth of it."""
    v, r, steer = np.abs(log["speed"]), log["yaw_rate"], log["steer"]
    ay = log["ay"] if "ay" in log and np.any(np.isfinite(log["ay"])) else v * r
    ok = (v > 3.0) & (np.abs(r) > 0.02) & (np.abs(ay) < 3.0) & np.isfinite(steer) & np.isfinite(ay)
    if ok.sum() < 200:
        return
    x = (wheelbase / v[ok] + understeer * v[ok]) * r[ok]
    y = steer[ok]
    ss = float(np.dot(x, x))
    slope = float(np.dot(x, y) / ss)
    se = float(np.sqrt(np.sum((y - slope * x) ** 2) / (len(y) - 1) / ss))
    if 5.0 < slope < 40.0 and se < 0.1 * slope:
        raise LogFormatError(f"{log.source}: column 'steer': over {int(ok.sum())} rows of cornering the steer is "
                             f"{slope:.3g} times the road-wheel angle the yaw rate and the vehicle's wheelbase "
                             f"({wheelbase:g} m) give (1 expected); it looks like the hand-wheel angle, expected the "
                             "front road-wheel angle (divide by the steering ratio; 'ratio' in a channel map)")


_NEVER_EMPTY = ("t", "speed", "steer", "yaw_rate")


def _read_fast(path: Path, keep: tuple[str, ...] | None = None, required: tuple[str, ...] = REQUIRED) \
        -> DriveLog | None:
    """pyarrow's multi-threaded CSV parser; None whenever the file is not plainly well formed."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    try:
        opener = gzip.open if path.suffix.lower() == ".gz" else open
        with opener(path, "rb") as fh:
            first = fh.readline()
        if first.startswith(b"\xef\xbb\xbf") or not first.strip():
            return None  # BOM or empty: the strict reader explains or handles it
        names = [h.strip() for h in first.decode("utf-8").rstrip("\r\n").split(",")]
        if len(set(names)) != len(names) or any(not n for n in names) or any(c not in names for c in required):
            return None
        wanted = names if keep is None else [n for n in names if n in keep]
        table = pacsv.read_csv(
            path, convert_options=pacsv.ConvertOptions(column_types={n: pa.float64() for n in wanted},
                                                       strings_can_be_null=True, include_columns=wanted))
    except Exception:  # any parsing problem: the strict reader names row and column
        return None
    if table.num_rows == 0 or table.column_names != wanted:
        return None
    names = wanted
    columns = {n: table.column(n).to_numpy(zero_copy_only=False).astype(float, copy=False) for n in names}
    for c in _NEVER_EMPTY:
        if c in columns and not np.all(np.isfinite(columns[c])):
            return None
    known = {c for c, _, _ in SCHEMA} | set(TRUTH_COLUMNS)
    for c in known & set(columns):
        if np.any(np.isinf(columns[c])):
            return None
    if np.any(np.diff(columns["t"]) <= 0):
        return None
    return DriveLog(columns, str(path))


def _read_strict(path: Path, required: tuple[str, ...] = REQUIRED) -> DriveLog:
    source = str(path)
    try:
        raw = path.read_bytes()
        if path.suffix.lower() == ".gz":
            raw = gzip.decompress(raw)
    except OSError as exc:
        raise LogFormatError(f"{source}: cannot read: {exc.strerror or exc}") from None
    except EOFError:
        raise LogFormatError(f"{source}: the gzip stream ends early (truncated file)") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise LogFormatError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader)
    except StopIteration:
        raise LogFormatError(f"{source}: empty file, expected a header row with columns "
                             f"{', '.join(required)}") from None
    header = [h.strip() for h in header]
    seen = set()
    for h in header:
        if h in seen:
            raise LogFormatError(f"{source}: row 1: duplicate column '{h}'")
        seen.add(h)
    if len(header) == 1 and required:
        for delim, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars")):
            if delim in header[0]:
                raise LogFormatError(f"{source}: row 1: the header is separated by {name} ({header[0][:60]!r}); a "
                                     f"drive log is comma-separated (a table with its own delimiter and names goes "
                                     f"through a channel map: --map, docs/formats.md)")
    for c in required:
        if c not in seen:
            raise LogFormatError(f"{source}: row 1: missing required column '{c}'")
    known = {c for c, _, _ in SCHEMA} | set(TRUTH_COLUMNS)
    cols_in = [c for c in header if c]
    values: dict[str, list] = {c: [] for c in cols_in}
    idx = {c: header.index(c) for c in cols_in}
    never_empty = {"t", "speed", "steer", "yaw_rate"}
    for row_no, row in enumerate(reader, start=2):
        if not row or all(not x.strip() for x in row):
            continue
        if len(row) != len(header):
            raise LogFormatError(f"{source}: row {row_no}: {len(row)} fields, expected {len(header)} "
                                 f"(truncated or malformed line)")
        for c in cols_in:
            if c in known:
                values[c].append(_float(row[idx[c]], source, row_no, c, c not in never_empty))
            else:  # extra columns are kept (as numbers where they are numbers) and ignored
                try:
                    values[c].append(float(row[idx[c]]))
                except ValueError:
                    values[c].append(math.nan)
    if not values["t"]:
        raise LogFormatError(f"{source}: header only, expected at least one data row")
    cols = {c: np.asarray(v, float) for c, v in values.items()}
    t = cols["t"]
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if len(bad):
        r = int(bad[0]) + 3
        raise LogFormatError(f"{source}: row {r}, column 't': {float(t[bad[0] + 1])!r} is not after the previous "
                             f"time {float(t[bad[0]])!r}; t must be strictly increasing")
    return DriveLog(cols, source)


def write_rows_csv(path: Path, rows: list[dict]) -> None:
    """Rows of dicts as a CSV table, atomically: every key a column, in order of first appearance (empty where a
    row has none), floats in their shortest round-trip digits; :func:`read_rows_csv` reads it back."""
    keys = list(dict.fromkeys(k for r in rows for k in r))  # every column, in order of first appearance

    def w(fh):
        wr = csv.DictWriter(fh, fieldnames=keys, lineterminator="\n", restval="")
        wr.writeheader()
        for r in rows:
            wr.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})

    atomic_write(path, w)


def read_rows_csv(path: Path) -> list[dict]:
    """Rows of a CSV table :func:`write_rows_csv` wrote, numbers and booleans parsed back."""

    def conv(v: str):
        if v in ("True", "False"):
            return v == "True"
        try:
            return int(v)
        except ValueError:
            pass
        try:
            return float(v)
        except ValueError:
            return v

    with open(path, newline="") as fh:
        return [{k: conv(v) for k, v in r.items()} for r in csv.DictReader(fh)]
