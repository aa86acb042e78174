"""ROS 2 bags and other MCAP files to channels (the ``mcap`` and ``mcap-ros2-support`` packages).

:func:`mcap_channels` is the reader :func:`toolkit.logs.channels.read_mapped` uses for ``.mcap`` files. A channel
the map names is a numeric field of the messages on one topic, written ``TOPIC.FIELD``: the topic up to its
first dot (ROS topic names hold none), then the field's path, ``[k]`` indexing an array::

    /imu/data.angular_velocity.z            sensor_msgs/msg/Imu
    /odom.twist.twist.linear.x              nav_msgs/msg/Odometry
    /gnss/vel.twist.linear.y                geometry_msgs/msg/TwistStamped
    /gnss/fix.status.status                 sensor_msgs/msg/NavSatFix
    /gnss/fix.position_covariance[0]

Messages are CDR with ROS 2 message definitions (what ``ros2 bag record`` writes), or JSON. Each sample's
time is the message's ``header.stamp`` where it has a ``std_msgs/Header`` (when the data was measured),
otherwise the message's log time (when the recorder received it); ``[options] stamps = "log"`` in the
channel map takes the log time for every topic (a driver that leaves its stamps at zero, or stamps on
another clock). Times count from the earliest sample of the mapped topics, in whole nanoseconds before
they become seconds.

Frames (REP 103: body axes forward-left-up, FLU, as ISO 8855; local earth axes east-north-up, ENU) are the
channel map's ``frame`` and ``velocity`` keys (:mod:`toolkit.logs.channels`): a body signal logged
forward-right-down (``frame = "FRD"``, the aerospace and NED convention) changes sign about z and along y,
and a receiver's velocity in ENU or NED gives the course and the ground speed.

Refused, each with the file, topic or field named: a file that is not MCAP; one that cannot be read to its
end (a recording cut off: ``mcap recover`` rewrites what it holds); a mapped topic the file does not have or
has no message on; a field its message type does not have, or that is not a number (a string, a nested
message, an array not indexed); messages in an encoding other than CDR and JSON; a message that does not
decode with its schema; header stamps that are all zero.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Callable

import numpy as np

from .drivelog import LogFormatError

STAMPS = ("header", "log")
"""Where a sample's time comes from: the message's ``header.stamp`` (the log time where it has none), or
the log time for every topic."""
MAGIC = b"\x89MCAP0\r\n"
"""The first bytes of every MCAP file (format version 0)."""
_INDEX = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")


def split_channel(name: str) -> tuple[str, list]:
    """``TOPIC.FIELD[k].SUB`` to the topic and the field path (names and indices)."""
    topic, dot, rest = name.partition(".")
    if not dot or not topic or not rest:
        raise LogFormatError(f"channel '{name}': an MCAP channel is TOPIC.FIELD (e.g. /imu/data.angular_velocity.z)")
    path = []
    for part in rest.split("."):
        m = _INDEX.match(part)
        if not m:
            raise LogFormatError(f"channel '{name}': '{part}' is not a field name (letters, digits and _, "
                                 f"optionally indexed as name[k])")
        path.append(m.group(1))
        path.extend(int(k) for k in re.findall(r"\[(\d+)\]", m.group(2)))
    return topic, path


def _fields(obj) -> list[str]:
    if isinstance(obj, dict):
        return list(obj)
    return list(getattr(obj, "__slots__", ()) or [k for k in vars(obj) if not k.startswith("_")])


def _is_message(obj) -> bool:
    return isinstance(obj, dict) or hasattr(obj, "__slots__") or hasattr(obj, "__dict__")


def _field(msg, path: list, where: str):
    """The number at ``path`` in a decoded message."""
    v = msg
    done = ""
    for p in path:
        if isinstance(p, int):
            if not isinstance(v, (list, tuple, bytes, np.ndarray)):
                raise LogFormatError(f"{where}: '{done}' is not an array; [{p}] cannot index it")
            if p >= len(v):
                raise LogFormatError(f"{where}: '{done}' has {len(v)} elements; [{p}] is past its end")
            v = v[p]
            done += f"[{p}]"
            continue
        if isinstance(v, (list, tuple, bytes, np.ndarray)) or not _is_message(v) or isinstance(v, (str, int, float)):
            raise LogFormatError(f"{where}: '{done}' is not a message; it has no field '{p}'")
        names = _fields(v)
        if p not in names:
            raise LogFormatError(f"{where}: {'the message' if not done else repr(done)} has no field '{p}' "
                                 f"(its fields: {', '.join(names) or 'none'})")
        v = v[p] if isinstance(v, dict) else getattr(v, p)
        done = f"{done}.{p}" if done else p
    if isinstance(v, bool) or isinstance(v, (int, float, np.integer, np.floating)):
        return float(v)
    if isinstance(v, (list, tuple, bytes, np.ndarray)):
        raise LogFormatError(f"{where}: '{done}' is an array of {len(v)}: name one element, {done}[k]")
    if isinstance(v, str):
        raise LogFormatError(f"{where}: '{done}' is a string, not a number")
    raise LogFormatError(f"{where}: '{done}' is a message (fields {', '.join(_fields(v))}), not a number: "
                         f"name one of its fields")


def _stamp_ns(msg) -> int | None:
    """``header.stamp`` in ns, or None where the message has no header stamp."""
    try:
        h = msg["header"] if isinstance(msg, dict) else getattr(msg, "header")
        s = h["stamp"] if isinstance(h, dict) else getattr(h, "stamp")
        sec = s["sec"] if isinstance(s, dict) else getattr(s, "sec")
        nsec = s["nanosec"] if isinstance(s, dict) else getattr(s, "nanosec")
        return int(sec) * 1_000_000_000 + int(nsec)
    except (AttributeError, KeyError, TypeError, ValueError):
        return None


def _messages(path: Path, topics: set):
    """``topic -> [(log time ns, message record, schema name, decoder)]`` for ``topics``, every topic of the
    file, and how many messages were read: one linear pass with CRCs checked."""
    from mcap.reader import NonSeekingReader
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    out: dict[str, list] = {t: [] for t in topics}
    seen: dict[str, str] = {}
    count = 0
    try:
        fh = open(path, "rb")
    except OSError as e:
        raise LogFormatError(f"{path}: cannot read: {e.strerror or e}") from None
    with fh:
        if fh.read(len(MAGIC)) != MAGIC:
            raise LogFormatError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
        fh.seek(0)
        # streamed, never the whole file in memory; no record can be longer than the file
        reader = NonSeekingReader(fh, validate_crcs=True, record_size_limit=path.stat().st_size + 1)
        try:
            for schema, channel, msg in reader.iter_messages(log_time_order=False):
                count += 1
                name = schema.name if schema is not None else "(no schema)"
                seen.setdefault(channel.topic, name)
                if channel.topic not in out:
                    continue
                enc = channel.message_encoding
                decode: Callable | None
                if enc == "json":
                    decode = json.loads
                elif enc == "cdr" and schema is not None and schema.encoding == "ros2msg":
                    decode = factory.decoder_for(enc, schema)
                else:
                    raise LogFormatError(f"{path}: topic '{channel.topic}' is in message encoding '{enc}' (schema "
                                         f"encoding '{schema.encoding if schema else 'none'}'): evstab reads ROS 2 "
                                         f"CDR (ros2msg schemas) and JSON")
                out[channel.topic].append((msg.log_time, msg.data, name, decode))
        except LogFormatError:
            raise
        except Exception as e:  # a cut-off or damaged file: McapError, and struct, zstd and lz4 errors
            raise LogFormatError(f"{path}: the file cannot be read past its message {count} ({type(e).__name__}: "
                                 f"{e}); a recording cut off can be recovered with 'mcap recover'") from None
    return out, seen, count


def mcap_channels(path, names, stamps: str = "header") -> dict:
    """The channels ``names`` (``TOPIC.FIELD``) of the MCAP file ``path``, ``name -> (time stamps [s] from the
    earliest sample of the mapped topics, values, None)`` (see the module)."""
    path = Path(path)
    if stamps not in STAMPS:
        raise LogFormatError(f"{path}: stamps = {stamps!r}: expected one of {', '.join(STAMPS)}")
    wanted = {n: split_channel(n) for n in names}
    msgs, seen, count = _messages(path, {t for t, _ in wanted.values()})
    times: dict[str, np.ndarray] = {}
    decoded: dict[str, list] = {}
    for topic, rows in msgs.items():
        if topic not in seen:
            users = ", ".join(n for n, (t, _) in wanted.items() if t == topic)
            raise LogFormatError(f"{path}: no topic '{topic}' (mapped as {users}); the file's topics: "
                                 f"{', '.join(f'{t} ({s})' for t, s in sorted(seen.items())) or 'none'}")
        objs, ns = [], []
        for k, (log_ns, data, schema, decode) in enumerate(rows):
            try:
                m = decode(data)
            except Exception as e:  # CDR shorter than its schema, JSON that does not parse
                raise LogFormatError(f"{path}: message {k} on topic '{topic}' ({schema}) does not decode: "
                                     f"{type(e).__name__}: {e}") from None
            objs.append(m)
            st = _stamp_ns(m) if stamps == "header" else None
            ns.append(log_ns if st is None else st)
        if stamps == "header" and objs and _stamp_ns(objs[0]) is not None and not any(ns):
            raise LogFormatError(f"{path}: topic '{topic}': every header stamp is zero (its driver does not set "
                                 f"them): give [options] stamps = \"log\" in the channel map")
        decoded[topic] = objs
        times[topic] = np.array(ns, dtype=np.int64)
    first = min((int(ts.min()) for ts in times.values() if len(ts)), default=0)
    out = {}
    for n, (topic, fpath) in wanted.items():
        objs = decoded[topic]
        if not objs:
            raise LogFormatError(f"{path}: no message on topic '{topic}' ({seen[topic]}; mapped as '{n}')")
        where = f"{path}: topic '{topic}' ({seen[topic]}), channel '{n}'"
        vals = np.array([_field(m, fpath, where) for m in objs], float)
        out[n] = ((times[topic] - first) / 1e9, vals, None)
    return out
