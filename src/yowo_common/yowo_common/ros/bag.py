"""rosbag2 (MCAP / sqlite3) reading and writing with rosbags, carrying rosidl
message objects: payloads are (de)serialised with rclpy, so the same message
classes flow through bags, nodes and the offline CLI."""
from __future__ import annotations

import functools
import importlib
import os
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import (ConnectionExtRosbag2, Qos, QosDurability, QosHistory, QosLiveliness,
                                QosReliability, QosTime)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

_NO_TIME = QosTime(sec=0, nsec=0)
# Offered QoS of latched topics (/tf_static, maps): reliable + transient-local.
LATCHED_QOS = Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
                  durability=QosDurability.TRANSIENT_LOCAL, deadline=_NO_TIME, lifespan=_NO_TIME,
                  liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_NO_TIME,
                  avoid_ros_namespace_conventions=False)

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


@functools.cache
def message_class(msgtype: str):
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
    latched: bool = False        # recorded with transient-local durability


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


def open_reader(path) -> Reader:
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such recording")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises several types for damaged files
        raise BagError(f"{path}: cannot open recording: {exc}") from exc
    return reader


def list_topics(path) -> list[BagTopic]:
    reader = open_reader(path)
    try:
        return [BagTopic(c.topic, c.msgtype, c.msgcount, qos_is_latched(c)) for c in reader.connections]
    finally:
        reader.close()


@dataclass(frozen=True)
class RawMessage:
    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes
    latched: bool


def read_raw(path, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
    """Serialised messages in log-time order. A damaged file ends the iteration
    with a BagError after every readable message."""
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


def read_messages(path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, object]]:
    """Yield (topic, log time [ns], message object) in log-time order."""
    for raw in read_raw(path, topics):
        yield raw.topic, raw.log_time_ns, deserialize_message(raw.data, message_class(raw.msgtype))


def qos_is_latched(conn) -> bool:
    ext = conn.ext
    if not isinstance(ext, ConnectionExtRosbag2):
        return False
    return any(q.durability == QosDurability.TRANSIENT_LOCAL for q in ext.offered_qos_profiles or [])
