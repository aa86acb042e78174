"""CAN traces to channels: a BLF or ASC trace (python-can reads it) decoded with the car's DBC (cantools).

:func:`can_channels` is the reader :func:`toolkit.logs.channels.read_mapped` uses for ``.blf`` and ``.asc``
files: each channel the map names is a DBC signal, written ``SIGNAL`` where one message of the DBC carries
a signal of that name, or ``MESSAGE.SIGNAL``; its samples are the frames of that message in the trace
(their time stamps, less the trace's first frame's), physical values by the DBC's scale and offset, its
unit the DBC's. A multiplexed signal has a sample only in the frames whose multiplexer selects it. Error
frames and remote frames are skipped.

Refused, each with the file, message or signal named: a trace without a DBC; a DBC that does not load; a
mapped signal the DBC does not have, or has in several messages (name it as ``MESSAGE.SIGNAL``); a mapped
message with no frame in the trace; a frame too short for its message; a trace that cannot be read to its
end (a garbled ASC line) or ends early (a BLF shorter than its header's file size, an ASC without its closing
``End TriggerBlock`` line). Beside the channels it names the mapped messages whose frames came
late (:func:`frame_gaps`): an interval longer than :data:`LATE_FACTOR` times the message's median.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .drivelog import LogFormatError

LATE_FACTOR = 3.0
"""A frame more than this many median intervals after the previous one of its message came late (a lost or
delayed frame: the cycle time of a CAN message is fixed by the car's network design)."""


def _load_dbc(dbc):
    import cantools
    if dbc is None:
        raise LogFormatError("a CAN trace needs the car's DBC to decode it: give --dbc CAR.dbc (or dbc = \"CAR.dbc\" "
                             "in the channel map's [options])")
    try:
        return cantools.database.load_file(str(dbc), database_format="dbc")
    except FileNotFoundError:
        raise LogFormatError(f"{dbc}: no such file (the DBC)") from None
    except Exception as e:  # cantools raises its own parse errors and ValueErrors
        raise LogFormatError(f"{dbc}: not a DBC cantools can read: {e}") from None


def _resolve(db, dbc, names):
    """``name -> (message, signal)`` for the mapped names."""
    by_signal: dict[str, list] = {}
    by_full = {}
    for m in db.messages:
        for s in m.signals:
            by_signal.setdefault(s.name, []).append((m, s))
            by_full[f"{m.name}.{s.name}"] = (m, s)
    out = {}
    for n in names:
        if n in by_full:
            out[n] = by_full[n]
            continue
        hits = by_signal.get(n, [])
        if not hits:
            raise LogFormatError(f"{dbc}: no signal '{n}' in any message (the channel map names it; the DBC's "
                                 f"signals are written SIGNAL or MESSAGE.SIGNAL)")
        if len(hits) > 1:
            raise LogFormatError(f"{dbc}: signal '{n}' is in {len(hits)} messages "
                                 f"({', '.join(m.name for m, _ in hits)}): name it as MESSAGE.SIGNAL")
        out[n] = hits[0]
    return out


def _frames(path: Path, ids: set) -> tuple[dict, float | None]:
    """``frame id -> [(time, data), ...]`` of the frames with those ids, and the trace's first time stamp."""
    import can
    reader_cls = can.BLFReader if path.suffix.lower() == ".blf" else can.ASCReader
    frames: dict[int, list] = {i: [] for i in ids}
    first: float | None = None
    count = 0
    blf = reader_cls is can.BLFReader
    try:
        with reader_cls(str(path)) as reader:
            declared = reader.file_size if isinstance(reader, can.BLFReader) else None
            for msg in reader:
                count += 1
                if first is None:
                    first = float(msg.timestamp)
                if msg.is_error_frame or msg.is_remote_frame or msg.arbitration_id not in frames:
                    continue
                frames[msg.arbitration_id].append((float(msg.timestamp), bytes(msg.data)))
    except Exception as e:  # python-can raises struct, zlib, value and its own errors on a damaged file
        raise LogFormatError(f"{path}: the trace cannot be read past its frame {count}: "
                             f"{type(e).__name__}: {e}") from None
    # python-can stops quietly where a file ends early; the file itself says where it should end
    size = path.stat().st_size
    if blf and declared and size < declared:
        raise LogFormatError(f"{path}: truncated: {size} bytes where its header says {declared} (the trace cannot "
                             f"be read past its frame {count})")
    if not blf and not _asc_closed(path):
        raise LogFormatError(f"{path}: truncated: no 'End TriggerBlock' line after its frame {count} (an ASC trace "
                             f"ends with one)")
    return frames, first


def _asc_closed(path: Path) -> bool:
    """Whether the ASC trace's last non-blank line closes its trigger block."""
    with open(path, "rb") as fh:
        fh.seek(max(0, path.stat().st_size - 4096))
        tail = fh.read().decode("latin-1").splitlines()
    last = next((ln.strip() for ln in reversed(tail) if ln.strip()), "")
    return last.lower().startswith("end triggerblock")


def can_channels(path, names, dbc) -> tuple[dict, list[str]]:
    """The channels ``names`` of the CAN trace ``path`` decoded with ``dbc``, ``name -> (time stamps [s],
    physical values, unit)`` (see the module), and :func:`frame_gaps` of the mapped messages (one read of the
    trace for both)."""
    path = Path(path)
    db = _load_dbc(dbc)
    wanted = _resolve(db, dbc, names)
    frames, first = _frames(path, {m.frame_id for m, _ in wanted.values()})
    decoded = {}
    out = {}
    for n, (m, s) in wanted.items():
        fr = frames[m.frame_id]
        if not fr:
            raise LogFormatError(f"{path}: no frame of message '{m.name}' (id 0x{m.frame_id:X}), which carries "
                                 f"'{s.name}' (mapped as '{n}')")
        if m.frame_id not in decoded:
            rows = []
            for k, (ts, data) in enumerate(fr):
                try:
                    rows.append((ts, m.decode(data, decode_choices=False, scaling=True)))
                except Exception as e:  # a frame shorter than the message, a multiplexer value the DBC lacks
                    raise LogFormatError(f"{path}: frame {k} of message '{m.name}' (id 0x{m.frame_id:X}, t = "
                                         f"{ts - first:.6f} s) does not decode with {dbc}: {e}") from None
            decoded[m.frame_id] = rows
        rows = decoded[m.frame_id]
        ts = np.array([t for t, d in rows if s.name in d], float) - first
        vals = np.array([float(d[s.name]) for t, d in rows if s.name in d], float)
        if not len(ts):
            raise LogFormatError(f"{path}: no frame of message '{m.name}' carries '{s.name}' (its multiplexer never "
                                 f"selects it)")
        out[n] = (ts, vals, s.unit or "")
    return out, frame_gaps({m.frame_id: m for m, _ in wanted.values()}, frames, 0.0 if first is None else first)


def frame_gaps(msgs: dict, frames: dict, first: float) -> list[str]:
    """The messages ``msgs`` (frame id -> message) whose ``frames`` (as :func:`_frames` reads them) came late,
    one line each: how many intervals exceeded :data:`LATE_FACTOR` times the message's median, and the longest
    (its time from the trace's ``first`` frame)."""
    out = []
    for i, m in sorted(msgs.items()):
        ts = np.array([t for t, _ in frames[i]], float)
        if len(ts) < 3:
            continue
        dt = np.diff(ts)
        late = dt > LATE_FACTOR * np.median(dt)
        if late.any():
            k = int(np.argmax(dt))
            out.append(f"late frames: message '{m.name}' (id 0x{i:X}): {int(late.sum())} of {len(dt)} intervals longer than "
                       f"{LATE_FACTOR:g} x its median {1000 * np.median(dt):.1f} ms, the longest {1000 * dt[k]:.1f} ms "
                       f"at t = {ts[k] - first:.3f} s")
    return out
