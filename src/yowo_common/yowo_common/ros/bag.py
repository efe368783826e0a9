"""rosbag2 (MCAP / sqlite3) reading and writing with rosbags, carrying rosidl
message objects: payloads are (de)serialised with rclpy, so the same message
classes flow through bags, nodes and the offline CLI."""

from __future__ import annotations

import functools
import heapq
import importlib
import io
import mmap
import os
import re
import struct
import sys
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.stream_reader import StreamReader
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

_NO_TIME = QosTime(sec=0, nsec=0)
# Offered QoS of latched topics (/tf_static, maps): reliable + transient-local.
LATCHED_QOS = Qos(
    history=QosHistory.KEEP_LAST,
    depth=1,
    reliability=QosReliability.RELIABLE,
    durability=QosDurability.TRANSIENT_LOCAL,
    deadline=_NO_TIME,
    lifespan=_NO_TIME,
    liveliness=QosLiveliness.AUTOMATIC,
    liveliness_lease_duration=_NO_TIME,
    avoid_ros_namespace_conventions=False,
)

# Our own interface packages, registered into rosbags' typestore from their .msg text.
OWN_INTERFACE_PACKAGES = ("yowo_msgs",)


class BagError(RuntimeError):
    """A recording that cannot be read or written; the message names the file."""


def interface_share_dir(pkg: str) -> Path:
    """share/<pkg> of an installed interface package: a sourced ROS workspace
    (AMENT_PREFIX_PATH) or the venv the wheels and our build installed into."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    for prefix in prefixes:
        share = Path(prefix) / "share" / pkg
        if (share / "package.xml").exists():
            return share
    raise BagError(f"interface package '{pkg}' is not installed under {prefixes} (run 'make setup')")


@functools.cache
def typestore():
    store = get_typestore(Stores.ROS2_JAZZY)
    for pkg in OWN_INTERFACE_PACKAGES:
        msg_dir = interface_share_dir(pkg) / "msg"
        types = {}
        for path in sorted(msg_dir.glob("*.msg")):
            types.update(get_types_from_msg(path.read_text(), f"{pkg}/msg/{path.stem}"))
        store.register(types)
    return store


def msgtype_of(msg) -> str:
    """'sensor_msgs/msg/Image' for a rosidl message object."""
    return f"{type(msg).__module__.split('.')[0]}/msg/{type(msg).__name__}"


# The interface packages whose message classes a recording's type names may select: the ROS
# message packages YOWO depends on and its own. A type name is untrusted text from a file;
# importing whatever module it names would run code planted beside the recording.
KNOWN_INTERFACE_PACKAGES = frozenset(
    {
        "builtin_interfaces",
        "std_msgs",
        "sensor_msgs",
        "geometry_msgs",
        "nav_msgs",
        "visualization_msgs",
        "tf2_msgs",
        "rosgraph_msgs",
        "diagnostic_msgs",
        "stereo_msgs",
        "shape_msgs",
        "trajectory_msgs",
        "statistics_msgs",
        "rcl_interfaces",
        "unique_identifier_msgs",
        "action_msgs",
        "lifecycle_msgs",
        *OWN_INTERFACE_PACKAGES,
    }
)
_MSGTYPE = re.compile(r"^(?P<pkg>[a-z][a-z0-9_]*)/msg/(?P<name>[A-Z][A-Za-z0-9]*)$")


def unknown_type_reason(msgtype: str) -> str:
    """Why a recording's message type is not read ('' when it is a known type)."""
    m = _MSGTYPE.match(msgtype)
    if m is None:
        return f"'{msgtype}' is not a ROS 2 message type name (package/msg/Name)"
    if m["pkg"] not in KNOWN_INTERFACE_PACKAGES:
        return f"'{msgtype}' is not from an interface package YOWO reads ({m['pkg']})"
    return ""


@functools.cache
def message_class(msgtype: str):
    """The rosidl class of a known message type; BagError for any other."""
    if why := unknown_type_reason(msgtype):
        raise BagError(f"unknown message type: {why}")
    pkg, kind, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError) as exc:
        raise BagError(f"message type '{msgtype}' is not installed in this environment") from exc


@dataclass(frozen=True)
class BagTopic:
    name: str
    msgtype: str
    count: int
    latched: bool = False  # recorded with transient-local durability


class BagWriter:
    """Write rosidl messages to a new rosbag2 (MCAP by default)."""

    def __init__(self, path, storage: str = "mcap"):
        self.path = Path(path)
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        if self.path.exists():
            raise BagError(f"{self.path}: already exists; refusing to overwrite a recording")
        self._writer = Writer(self.path, version=9, storage_plugin=plugin)
        self._connections = {}

    def __enter__(self):
        self._writer.open()
        return self

    def __exit__(self, *exc):
        self._writer.close()

    def write(self, topic: str, msg, stamp_ns: int, latched: bool = False) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            msgtype = msgtype_of(msg)
            qos = [LATCHED_QOS] if latched else []
            conn = self._writer.add_connection(topic, msgtype, typestore=typestore(), offered_qos_profiles=qos)
            self._connections[topic] = conn
        self._writer.write(conn, int(stamp_ns), serialize_message(msg))


# A recording: one rosbag2 (directory or .mcap file), or several read as one in log-time order
# (walks of one building recorded apart, e.g. a second walk that the walk guidance suggested).
Recording = str | os.PathLike | Sequence[str | os.PathLike]


def recording_paths(recording: Recording) -> list[Path]:
    """The files or directories of a recording, in the order given."""
    if isinstance(recording, (str, os.PathLike)):
        return [Path(recording)]
    paths = [Path(p) for p in recording]
    if not paths:
        raise BagError("no recording given")
    return paths


def recording_label(recording: Recording) -> str:
    """How a recording is named in messages: its path, or its paths joined by ' + '."""
    return " + ".join(str(p) for p in recording_paths(recording))


def open_reader(path):
    """A rosbags Reader; for an MCAP whose end is missing (recorder killed, disk full,
    power lost: no summary, maybe no metadata.yaml) a RecoveredMcap of what is readable."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such recording")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises several types for damaged files
        files = sorted(path.glob("*.mcap")) if path.is_dir() else [path] if path.suffix == ".mcap" else []
        if len(files) == 1:
            recovered = RecoveredMcap(files[0], f"{exc}")
            if recovered.connections:
                return recovered
        raise BagError(f"{path}: cannot open recording: {exc}") from exc
    return reader


def recording_damage(recording: Recording) -> str:
    """What was recovered of a damaged recording ('' when it opens normally)."""
    damage = []
    for path in recording_paths(recording):
        reader = open_reader(path)
        reader.close()
        damage.append(getattr(reader, "damage", ""))
    return "; ".join(d for d in damage if d)


def _spans(recording: Recording) -> list[tuple[int, int]]:
    spans = []
    for path in recording_paths(recording):
        reader = open_reader(path)
        try:
            start, end = getattr(reader, "start_time", 0), getattr(reader, "end_time", 0)
        finally:
            reader.close()
        if 0 < start <= end:
            spans.append((int(start), int(end)))
    return spans


def recording_span(recording: Recording) -> tuple[int, int]:
    """Log times [ns] of a recording's first and last message ((0, 0) when unknown or empty)."""
    spans = _spans(recording)
    return (min(s for s, _ in spans), max(e for _, e in spans)) if spans else (0, 0)


def recording_gaps(recording: Recording) -> list[tuple[int, int]]:
    """(end, start) log times [ns] of the silences between the files of a recording read as
    one: where no file holds messages (none for one file, or files that overlap in time)."""
    gaps, end = [], None
    for s, e in sorted(_spans(recording)):
        if end is not None and s > end:
            gaps.append((end, s))
        end = e if end is None else max(end, e)
    return gaps


def list_topics(recording: Recording) -> list[BagTopic]:
    """The topics of a recording; a topic in several of its files is listed once, its
    messages counted over all (a topic whose type differs between files is an error)."""
    topics: dict[str, BagTopic] = {}
    for path in recording_paths(recording):
        reader = open_reader(path)
        try:
            for c in reader.connections:
                t = BagTopic(c.topic, c.msgtype, c.msgcount, qos_is_latched(c))
                seen = topics.get(t.name)
                if seen is not None and seen.msgtype != t.msgtype:
                    raise BagError(
                        f"{path}: topic {t.name} is {t.msgtype} here and {seen.msgtype} in an earlier recording "
                        f"of {recording_label(recording)}; recordings read as one must agree on each topic's type"
                    )
                if seen is not None:
                    t = BagTopic(t.name, t.msgtype, seen.count + t.count, seen.latched or t.latched)
                topics[t.name] = t
        finally:
            reader.close()
    return list(topics.values())


_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_FOOTER, _OP_CHUNK = 0x02, 0x06


def _records_of(data: bytes):
    """MCAP records (a chunk's contents included) in `data`, up to the first incomplete one."""
    from mcap.exceptions import EndOfFile

    try:
        yield from StreamReader(io.BytesIO(data), skip_magic=True, validate_crcs=True).records
    except EndOfFile:
        return


def _torn_chunk_records(body: bytes) -> bytes:
    """The records at the start of a chunk cut short: its header, then as much of its
    (decompressed) contents as the file holds."""
    (comp_len,) = struct.unpack_from("<I", body, 28)
    compression = body[32 : 32 + comp_len].decode()
    payload = body[32 + comp_len + 8 :]
    if compression == "":
        return payload
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompressobj().decompress(payload)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(payload)
    return b""


def _mcap_stream(file: Path):
    """(record, chunk index) of every readable record of an MCAP read front to back without
    its summary; the last item is (None, where and why the readable part ends)."""
    with open(file, "rb") as f:
        data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if file.stat().st_size else b""
    try:
        if data[:8] != _MCAP_MAGIC:
            yield None, "not an MCAP file (no magic at its start)"
            return
        pos, chunk = 8, 0
        while pos + 9 <= len(data):
            opcode, length = struct.unpack_from("<BQ", data, pos)
            if opcode == _OP_FOOTER:
                yield None, ""
                return
            body_end = pos + 9 + length
            if body_end > len(data):
                if opcode == _OP_CHUNK and len(data) - pos - 9 > 40:
                    try:
                        for rec in _records_of(_torn_chunk_records(bytes(data[pos + 9 :]))):
                            yield rec, chunk
                    except Exception:  # a torn compressed frame: what decoded is kept
                        pass
                    yield None, f"the file ends inside the chunk at byte {pos}: its complete messages are kept"
                    return
                break
            try:
                for rec in _records_of(bytes(data[pos:body_end])):
                    yield rec, chunk
            except Exception as exc:  # a damaged record (CRC): the stream ends before it
                yield None, f"a damaged record at byte {pos} ({exc}): the rest is skipped"
                return
            pos, chunk = body_end, chunk + 1
        yield None, f"the file ends inside a record at byte {pos}"
    finally:
        if isinstance(data, mmap.mmap):
            data.close()


@functools.lru_cache(maxsize=8)
def _scan_mcap(file: str, size: int, mtime_ns: int):
    """(channels, schemas, per-channel counts, why the readable part ended, first and last
    log time) of an MCAP read as a stream."""
    from mcap.records import Channel, Message, Schema

    channels, schemas, counts, stamps, end = {}, {}, {}, [], ""
    for record, info in _mcap_stream(Path(file)):
        if record is None:
            end = info
        elif isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
            stamps.append(record.log_time)
    span = (min(stamps), max(stamps)) if stamps else (0, 0)
    return channels, schemas, counts, end, span


class RecoveredMcap:
    """The readable part of an MCAP file without its end, read as a stream (what
    `ros2 bag reindex` and the MCAP stream reader recover), up to the last complete
    message. Messages come in file order, sorted by log time within each chunk (a
    recorder writes chunks in time order)."""

    def __init__(self, file: Path, open_error: str):
        self.file = Path(file)
        st = self.file.stat()
        channels, schemas, counts, why, (t0, t1) = _scan_mcap(str(self.file), st.st_size, st.st_mtime_ns)
        self.connections = []
        for cid, ch in sorted(channels.items()):
            schema = schemas.get(ch.schema_id)
            qos_text = ch.metadata.get("offered_qos_profiles", "")
            ext = ConnectionExtRosbag2(
                serialization_format=ch.message_encoding, offered_qos_profiles=parse_qos(qos_text) if qos_text else []
            )
            self.connections.append(
                Connection(cid, ch.topic, schema.name if schema else "", "", "", counts.get(cid, 0), ext, None)
            )
        total = sum(counts.values())
        span = f" ({(t1 - t0) / 1e9:.1f} s of recording)" if total else ""
        self.damage = (
            f"{self.file} ({st.st_size} bytes) is damaged ({open_error.rstrip('.')}); recovered "
            f"{total} messages{span}" + (f"; {why}" if why else "")
        )

    def messages(self, connections=None):
        from mcap.records import Message

        by_id = {c.id: c for c in (connections or self.connections)}
        pending, chunk = [], None
        for record, info in _mcap_stream(self.file):
            if record is None or info != chunk:
                for m in sorted(pending, key=lambda r: r.log_time):
                    yield by_id[m.channel_id], m.log_time, m.data
                pending, chunk = [], info
            if isinstance(record, Message) and record.channel_id in by_id:
                pending.append(record)

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class RawMessage:
    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes
    latched: bool


def read_raw(recording: Recording, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
    """Serialised messages in log-time order (a recording of several files: merged by log
    time). A damaged file ends the iteration with a BagError after every readable message;
    a file without its end is read up to its last readable message (see RecoveredMcap)."""
    paths = recording_paths(recording)
    wanted = None if topics is None else list(topics)
    if len(paths) == 1:
        yield from _read_raw(paths[0], wanted)
    else:
        yield from heapq.merge(*(_read_raw(p, wanted) for p in paths), key=lambda m: m.log_time_ns)


def _read_raw(path: Path, topics: list[str] | None) -> Iterator[RawMessage]:
    reader = open_reader(path)
    try:
        wanted = None if topics is None else set(topics)
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        latched = {c.id: qos_is_latched(c) for c in conns}
        try:
            for conn, stamp_ns, raw in reader.messages(connections=conns):
                yield RawMessage(conn.topic, conn.msgtype, stamp_ns, bytes(raw), latched[conn.id])
        except Exception as exc:
            raise BagError(f"{path}: recording is damaged after the last readable message: {exc}") from exc
    finally:
        reader.close()


def read_messages(recording: Recording, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, object]]:
    """Yield (topic, log time [ns], message object) in log-time order; topics of unknown
    message types (see unknown_type_reason) are not read."""
    known = [t.name for t in list_topics(recording) if not unknown_type_reason(t.msgtype)]
    wanted = known if topics is None else [t for t in topics if t in set(known)]
    for raw in read_raw(recording, wanted):
        yield raw.topic, raw.log_time_ns, deserialize_message(raw.data, message_class(raw.msgtype))


def qos_is_latched(conn) -> bool:
    ext = conn.ext
    if not isinstance(ext, ConnectionExtRosbag2):
        return False
    return any(q.durability == QosDurability.TRANSIENT_LOCAL for q in ext.offered_qos_profiles or [])
