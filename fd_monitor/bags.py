"""rosbag2 MCAP bags of fd_monitor topics: write, read into arrays, list.

Usable without ROS: bags are written and read with ``rosbags`` (MCAP storage, rosbag2
format version 9) and its ROS 2 Jazzy type store; nothing here imports rclpy. Messages on
fd_monitor topics are self-describing Float64MultiArrays (labels in ``layout.dim[0].label``,
the sample stamp in ``data[0]``; see :mod:`fd_monitor.nodes.conversions`), so a topic reads
back as arrays::

    arrays = read_bag("run1")["/plant/y"]
    arrays.stamps      # (K,) int64 sample indices k
    arrays.labels      # ("h1", "h2", "h3")
    arrays.values      # (K, 3)
    arrays.receive_ns  # (K,) int64 bag timestamps (receive time when recorded), ns

The CDR bytes rosbags writes are the bytes rclpy publishes, so ``record``/``replay`` move them
unchanged.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.errors import BagError, MessageError
from fd_monitor.nodes.conversions import ArrivalStamper, decode, encode_data, join_labels

__all__ = [
    "DIAGNOSTIC_ARRAY",
    "FLOAT64_MULTI_ARRAY",
    "BagWriter",
    "TopicArrays",
    "array_msg",
    "arrays_from",
    "bag_topics",
    "read_bag",
    "read_messages",
    "read_raw",
    "serialize_array",
    "write_bag",
]

FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"


@cache
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@dataclass(frozen=True)
class TopicArrays:
    """One Float64MultiArray topic of a bag as arrays.

    Attributes
    ----------
    topic : str
    labels : tuple of str
        (m,) channel names.
    stamps : numpy.ndarray
        (K,) int64 sample indices (in-band stamps; plain messages are numbered 0, 1, ...).
    values : numpy.ndarray
        (K, m) float64.
    receive_ns : numpy.ndarray
        (K,) int64 bag timestamps, ns.
    """

    topic: str
    labels: tuple[str, ...]
    stamps: np.ndarray
    values: np.ndarray
    receive_ns: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps.size)

    def column(self, label: str) -> np.ndarray:
        """(K,) the values of channel ``label``."""
        if label not in self.labels:
            raise BagError(f"{self.topic}: no channel {label!r} (channels: "
                           f"{', '.join(self.labels)})")
        return self.values[:, self.labels.index(label)]


def array_msg(labels: Sequence[str], stamp: int, values: Any) -> Any:
    """A stamped, labelled Float64MultiArray as a rosbags dataclass."""
    types = _typestore().types
    n = len(labels)
    data = np.asarray(encode_data(stamp, values), dtype=np.float64)
    if data.size - 1 != n:
        raise MessageError(f"{n} labels for {data.size - 1} values")
    dim = types["std_msgs/msg/MultiArrayDimension"](label=join_labels(labels), size=n,
                                                   stride=n)
    layout = types["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=1)
    return types[FLOAT64_MULTI_ARRAY](layout=layout, data=data)


def serialize_array(labels: Sequence[str], stamp: int, values: Any) -> bytes:
    """CDR bytes of :func:`array_msg` (what rclpy would publish)."""
    return bytes(_typestore().serialize_cdr(array_msg(labels, stamp, values),
                                            FLOAT64_MULTI_ARRAY))


class BagWriter:
    """Write a rosbag2 MCAP bag, topic by topic, message by message.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag folder to create; must not exist.

    Examples
    --------
    >>> with BagWriter(tmp / "bag") as w:                     # doctest: +SKIP
    ...     w.write_array("/plant/y", 0, ("h1",), [0.4], timestamp_ns=0)
    """

    def __init__(self, path: str | Path) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path}: already exists (a bag is never overwritten)")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path}: parent folder {self.path.parent} does not exist")
        try:
            self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"{self.path}: cannot create bag: {exc}") from None
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str = FLOAT64_MULTI_ARRAY) -> None:
        """Declare a topic (done implicitly by the first write of an array)."""
        if topic in self._conns:
            return
        if msgtype not in _typestore().types:
            raise BagError(f"{topic}: unknown message type {msgtype!r}")
        self._conns[topic] = self._writer.add_connection(topic, msgtype,
                                                         typestore=_typestore())
        self.counts[topic] = 0

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Write CDR bytes of an already declared topic."""
        self._writer.write(self._conns[topic], int(timestamp_ns), data)
        self.counts[topic] += 1

    def write_array(self, topic: str, stamp: int, labels: Sequence[str], values: Any,
                    timestamp_ns: int) -> None:
        """Write one stamped, labelled Float64MultiArray."""
        self.add_topic(topic)
        self.write_raw(topic, timestamp_ns, serialize_array(labels, stamp, values))

    def close(self) -> None:
        """Finish the bag (writes metadata.yaml)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_bag(path: str | Path, arrays: Iterable[TopicArrays]) -> Path:
    """Write topics given as arrays into a new MCAP bag, in bag-timestamp order.

    Messages with equal timestamps keep the order of ``arrays`` (e.g. u_k, y_k, truth_k).
    """
    items = list(arrays)
    events: list[tuple[int, int, int]] = []
    for i, a in enumerate(items):
        if a.values.shape != (a.stamps.size, len(a.labels)):
            raise BagError(f"{a.topic}: values of shape {a.values.shape}, expected "
                           f"({a.stamps.size}, {len(a.labels)})")
        events += [(int(t), i, j) for j, t in enumerate(a.receive_ns)]
    events.sort()
    with BagWriter(path) as w:
        for a in items:
            w.add_topic(a.topic)
        for t, i, j in events:
            a = items[i]
            w.write_array(a.topic, int(a.stamps[j]), a.labels, a.values[j], t)
    return Path(path)


def _open_reader(path: str | Path) -> Any:
    from rosbags.rosbag2 import Reader, ReaderError

    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    if not p.is_dir() or not (p / "metadata.yaml").is_file():
        raise BagError(f"{p}: not a rosbag2 bag (expected a folder with metadata.yaml)")
    try:
        reader = Reader(p)
        reader.open()
    except (ReaderError, OSError, KeyError, ValueError) as exc:
        raise BagError(f"{p}: not a readable rosbag2 bag: {exc}") from None
    return reader


def bag_topics(path: str | Path) -> dict[str, tuple[str, int]]:
    """topic -> (message type, message count) of a bag."""
    reader = _open_reader(path)
    try:
        out: dict[str, tuple[str, int]] = {}
        for c in reader.connections:
            t, n = out.get(c.topic, (c.msgtype, 0))
            out[c.topic] = (t, n + c.msgcount)
        return out
    finally:
        reader.close()


def _connections(reader: Any, path: str | Path, topics: Sequence[str] | None,
                 msgtype: str | None) -> list[Any]:
    present = {c.topic for c in reader.connections}
    if topics is not None:
        missing = [t for t in topics if t not in present]
        if missing:
            raise BagError(f"{path}: no topic {', '.join(missing)} in the bag (topics: "
                           f"{', '.join(sorted(present)) or 'none'})")
    return [c for c in reader.connections
            if (topics is None or c.topic in topics)
            and (msgtype is None or c.msgtype == msgtype)]


def read_messages(path: str | Path, topics: Sequence[str] | None = None
                  ) -> Iterator[tuple[str, int, Any]]:
    """Yield ``(topic, timestamp_ns, message)`` in bag order (rosbags dataclasses)."""
    reader = _open_reader(path)
    try:
        store = _typestore()
        conns = _connections(reader, path, topics, None)
        for conn, t, raw in reader.messages(connections=conns):
            yield conn.topic, t, store.deserialize_cdr(raw, conn.msgtype)
    finally:
        reader.close()


def read_raw(path: str | Path, topics: Sequence[str] | None = None
             ) -> Iterator[tuple[str, str, int, bytes]]:
    """Yield ``(topic, msgtype, timestamp_ns, cdr_bytes)`` in bag order."""
    reader = _open_reader(path)
    try:
        for conn, t, raw in reader.messages(connections=_connections(reader, path, topics,
                                                                     None)):
            yield conn.topic, conn.msgtype, t, bytes(raw)
    finally:
        reader.close()


def read_bag(path: str | Path, topics: Sequence[str] | None = None
             ) -> dict[str, TopicArrays]:
    """Read Float64MultiArray topics of a bag into :class:`TopicArrays`.

    Parameters
    ----------
    path : str or pathlib.Path
        The bag folder.
    topics : sequence of str, optional
        Topics to read (each must be in the bag); default every Float64MultiArray topic.

    Raises
    ------
    BagError
        Missing bag, not a bag, missing topic, or a malformed message (topic and stamp named).
    """
    reader = _open_reader(path)
    try:
        store = _typestore()
        conns = _connections(reader, path, topics, None)
        for c in conns:
            if topics is not None and c.msgtype != FLOAT64_MULTI_ARRAY:
                raise BagError(f"{path}: {c.topic} is {c.msgtype}, not {FLOAT64_MULTI_ARRAY}")
        conns = [c for c in conns if c.msgtype == FLOAT64_MULTI_ARRAY]
        acc: dict[str, tuple[list[int], list[np.ndarray], list[int]]] = {}
        labels: dict[str, tuple[str, ...]] = {}
        stampers: dict[str, ArrivalStamper] = {}
        for conn, t, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            first = labels.get(conn.topic)
            try:
                d = stampers.setdefault(conn.topic, ArrivalStamper()).stamp(
                    decode(msg, conn.topic, labels=first, allow_nan=True))
            except MessageError as exc:
                raise BagError(f"{path}: {exc}") from None
            if first is None:
                # Unlabelled (a user's driver): name the channels by position.
                labels[conn.topic] = d.labels or tuple(str(i) for i in range(d.values.size))
            ks, vs, ts = acc.setdefault(conn.topic, ([], [], []))
            ks.append(int(d.stamp or 0))
            vs.append(d.values)
            ts.append(int(t))
    finally:
        reader.close()
    out: dict[str, TopicArrays] = {}
    for c in conns:
        if c.topic in out:
            continue
        ks, vs, ts = acc.get(c.topic, ([], [], []))
        lab = labels.get(c.topic, ())
        vals = np.vstack(vs) if vs else np.zeros((0, len(lab)))
        out[c.topic] = TopicArrays(c.topic, lab, np.asarray(ks, dtype=np.int64), vals,
                                   np.asarray(ts, dtype=np.int64))
    return out


def arrays_from(topic: str, labels: Sequence[str], stamps: Any, values: Any,
                receive_ns: Any) -> TopicArrays:
    """Build a :class:`TopicArrays`, checking shapes."""
    v = np.asarray(values, dtype=float)
    s = np.asarray(stamps, dtype=np.int64).reshape(-1)
    if v.ndim != 2 or v.shape != (s.size, len(labels)):
        raise BagError(f"{topic}: values of shape {v.shape}, expected ({s.size}, "
                       f"{len(labels)})")
    return TopicArrays(topic, tuple(labels), s, v,
                       np.asarray(receive_ns, dtype=np.int64).reshape(-1))
