"""rosbag2 MCAP bags of fd_monitor topics, written: the one bag writer, and recovery.

Bags are rosbag2 bags (format version 9, MCAP storage) that rosbags and rosbag2 read;
fd_monitor writes them with the ``mcap`` package's record classes (zstd chunks with CRCs,
flushed at least every :data:`FLUSH_SECONDS` by ``record``), and ``bag recover``
(:func:`recover_bag`) rewrites every readable message of a damaged bag into a complete one.
The CDR bytes written are the bytes rclpy publishes, so ``record``/``replay`` move them
unchanged. Reading: :mod:`fd_monitor.wire.bag_scanner`, :mod:`fd_monitor.wire.bag_reader`.
"""

from __future__ import annotations

import itertools
import struct
import time
import zlib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import yaml
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from fd_monitor.model.errors import BagError, WrongLengthError
from fd_monitor.wire.bag_reader import TopicArrays, _typestore
from fd_monitor.wire.bag_scanner import MCAP_MAGIC, BagDamage, _scan
from fd_monitor.wire.conversions import encode_data, join_labels
from fd_monitor.wire.topics import FLOAT64_MULTI_ARRAY

__all__ = ["CHUNK_BYTES", "FLUSH_SECONDS", "BagWriter", "array_msg", "recover_bag",
           "serialize_array", "write_bag", "write_messages"]

#: Uncompressed bytes per chunk: a damaged chunk loses at most this much (~600 samples of a
#: 3-channel topic), at ~1 % more bytes than 1 MiB chunks.
CHUNK_BYTES = 64 * 1024
#: ``record`` writes a chunk once its oldest message is this old (s).
FLUSH_SECONDS = 0.5

def array_msg(labels: Sequence[str], stamp: int, values: Any) -> Any:
    """A stamped, labelled Float64MultiArray as a rosbags dataclass."""
    types = _typestore().types
    n = len(labels)
    data = np.asarray(encode_data(stamp, values), dtype=np.float64)
    if data.size - 1 != n:
        raise WrongLengthError(f"{n} labels for {data.size - 1} values")
    dim = types["std_msgs/msg/MultiArrayDimension"](label=join_labels(labels), size=n,
                                                   stride=n)
    layout = types["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=1)
    return types[FLOAT64_MULTI_ARRAY](layout=layout, data=data)


def serialize_array(labels: Sequence[str], stamp: int, values: Any) -> bytes:
    """CDR bytes of :func:`array_msg` (what rclpy would publish)."""
    return bytes(_typestore().serialize_cdr(array_msg(labels, stamp, values),
                                            FLOAT64_MULTI_ARRAY))


class BagWriter:
    """Write a rosbag2 MCAP bag (the one bag writer of fd_monitor), message by message.

    The ``.mcap`` file is an MCAP (profile ``ros2``, CDR messages, ``ros2msg`` schemas) that
    ``rosbags`` and rosbag2 read; ``metadata.yaml`` is written on :meth:`close`. Crash
    safety: messages are grouped in zstd chunks that each carry a CRC-32 of their content
    and repeat the schema and channel records of their messages, so every chunk can be
    read on its own; a chunk is written out (and the file flushed to the operating system)
    when it reaches ``chunk_bytes`` or when its oldest message is ``flush_seconds`` old
    (checked on every write and on :meth:`tick`). A writer that dies loses only the chunk
    it was filling; :func:`read_raw` reads such a file, and ``bag recover`` rewrites it.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag folder to create; must not exist.
    chunk_bytes : int
        Uncompressed size at which a chunk is written, bytes.
    flush_seconds : float, optional
        Write a chunk once its oldest message is this old (s, wall clock); None = only by
        size and on close (offline writers).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from fd_monitor.wire.bag_reader import read_bag
    >>> tmp = pathlib.Path(tempfile.mkdtemp())
    >>> with BagWriter(tmp / "bag") as w:
    ...     w.write_array("/plant/y", 0, ("h1",), [0.4], timestamp_ns=0)
    >>> read_bag(tmp / "bag")["/plant/y"].values
    array([[0.4]])
    """

    def __init__(self, path: str | Path, *, chunk_bytes: int = CHUNK_BYTES,
                 flush_seconds: float | None = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path}: already exists (a bag is never overwritten)")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path}: parent folder {self.path.parent} does not exist")
        self.file = self.path / f"{self.path.name}.mcap"
        try:
            self.path.mkdir()
            self._out: BinaryIO | None = self.file.open("xb")
        except OSError as exc:
            raise BagError(f"{self.path}: cannot create bag: {exc.strerror or exc}") from None
        self.chunk_bytes = int(chunk_bytes)
        self.flush_seconds = flush_seconds
        self._pos = 0
        self._crc = 0
        self._schemas: dict[str, Schema] = {}
        self._channels: dict[str, Channel] = {}
        self._hashes: dict[str, str] = {}
        self._pending: list[tuple[int, int, bytes]] = []
        self._pending_bytes = 0
        self._pending_since = 0.0
        self._chunk_indexes: list[ChunkIndex] = []
        self._compressor = zstandard.ZstdCompressor()
        self.counts: dict[str, int] = {}
        self._t_min = 2 ** 64 - 1
        self._t_max = 0
        rec = RecordBuilder()
        Header(profile="ros2", library="fd_monitor").write(rec)
        self._emit(MCAP_MAGIC + rec.end())
        self._out.flush()  # an MCAP file from the start, even if the writer dies at once

    def _emit(self, data: bytes) -> None:
        assert self._out is not None, "bag already closed"
        self._out.write(data)
        self._pos += len(data)
        self._crc = zlib.crc32(data, self._crc)

    def add_topic(self, topic: str, msgtype: str = FLOAT64_MULTI_ARRAY,
                  msgdef: str | None = None) -> None:
        """Declare a topic (done implicitly by the first write of an array).

        ``msgdef`` (the ``ros2msg`` definition) is needed only for types the ROS 2 Jazzy
        type store does not know.
        """
        if topic in self._channels:
            return
        if msgtype not in self._schemas:
            known = msgtype in _typestore().types
            if msgdef is None:
                if not known:
                    raise BagError(f"{topic}: unknown message type {msgtype!r}")
                msgdef, _ = _typestore().generate_msgdef(msgtype, ros_version=2)
            if known:
                self._hashes[msgtype] = _typestore().hash_rihs01(msgtype)
            self._schemas[msgtype] = Schema(id=len(self._schemas) + 1, name=msgtype,
                                            encoding="ros2msg", data=msgdef.encode())
        self._channels[topic] = Channel(id=len(self._channels) + 1, topic=topic,
                                        message_encoding="cdr",
                                        metadata={"offered_qos_profiles": "[]"},
                                        schema_id=self._schemas[msgtype].id)
        self.counts[topic] = 0

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Write CDR bytes of an already declared topic."""
        if topic not in self._channels:
            raise BagError(f"{self.path}: topic {topic} not declared (add_topic)")
        if not self._pending:
            self._pending_since = time.monotonic()
        t = int(timestamp_ns)
        self._pending.append((self._channels[topic].id, t, bytes(data)))
        self._pending_bytes += len(data) + 31
        self.counts[topic] += 1
        self._t_min, self._t_max = min(self._t_min, t), max(self._t_max, t)
        if self._pending_bytes >= self.chunk_bytes:
            self.flush()
        else:
            self.tick()

    def write_array(self, topic: str, stamp: int, labels: Sequence[str], values: Any,
                    timestamp_ns: int) -> None:
        """Write one stamped, labelled Float64MultiArray."""
        self.add_topic(topic)
        self.write_raw(topic, timestamp_ns, serialize_array(labels, stamp, values))

    def tick(self) -> None:
        """Write the chunk being filled if its oldest message is ``flush_seconds`` old."""
        if (self.flush_seconds is not None and self._pending
                and time.monotonic() - self._pending_since >= self.flush_seconds):
            self.flush()

    def flush(self) -> None:
        """Write the chunk being filled (if any) and flush the file to the OS."""
        if not self._pending:
            return
        by_id = {c.id: c for c in self._channels.values()}
        schemas = {s.id: s for s in self._schemas.values()}
        used = list(dict.fromkeys(cid for cid, _, _ in self._pending))
        rec = RecordBuilder()
        for sid in dict.fromkeys(by_id[c].schema_id for c in used):
            schemas[sid].write(rec)
        for cid in used:
            by_id[cid].write(rec)
        index: dict[int, list[tuple[int, int]]] = {cid: [] for cid in used}
        for cid, t, data in self._pending:
            index[cid].append((t, rec.count))
            Message(channel_id=cid, log_time=t, data=data, publish_time=t, sequence=0
                    ).write(rec)
        raw = rec.end()
        times = [t for _, t, _ in self._pending]
        chunk = Chunk(compression="zstd", data=self._compressor.compress(raw),
                      message_start_time=min(times), message_end_time=max(times),
                      uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw))
        rec = RecordBuilder()
        chunk.write(rec)
        chunk_start, chunk_len = self._pos, rec.count
        offsets = {}
        for cid, entries in index.items():
            offsets[cid] = chunk_start + rec.count
            MessageIndex(channel_id=cid, records=entries).write(rec)
        self._emit(rec.end())
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time, chunk_start_offset=chunk_start,
            chunk_length=chunk_len, message_index_offsets=offsets,
            message_index_length=self._pos - chunk_start - chunk_len, compression="zstd",
            compressed_size=len(chunk.data), uncompressed_size=len(raw)))
        self._pending, self._pending_bytes = [], 0
        assert self._out is not None
        self._out.flush()

    def close(self) -> None:
        """Finish the bag: last chunk, summary and footer, then ``metadata.yaml``."""
        if self._out is None:
            return
        self.flush()
        rec = RecordBuilder()
        DataEnd(data_section_crc=self._crc).write(rec)  # CRC of every byte before it
        self._emit(rec.end())
        summary_start = self._pos
        rec = RecordBuilder()
        groups: list[tuple[int, int, int]] = []
        opcode: int
        for opcode, records in (
                (Opcode.SCHEMA, list(self._schemas.values())),
                (Opcode.CHANNEL, list(self._channels.values())),
                (Opcode.STATISTICS, [self._statistics()]),
                (Opcode.CHUNK_INDEX, self._chunk_indexes)):
            start = rec.count
            for r in records:
                r.write(rec)
            if rec.count > start:
                groups.append((opcode, summary_start + start, rec.count - start))
        offset_start = summary_start + rec.count
        for opcode, start, length in groups:
            SummaryOffset(group_opcode=opcode, group_start=start, group_length=length
                          ).write(rec)
        summary = rec.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start),
                         zlib.crc32(summary))
        rec = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=offset_start,
               summary_crc=crc).write(rec)
        self._emit(summary + rec.end() + MCAP_MAGIC)
        out, self._out = self._out, None
        out.close()
        tmp = self.path / "metadata.yaml.tmp"
        tmp.write_text(yaml.safe_dump(self._metadata(), sort_keys=False), encoding="utf-8")
        tmp.replace(self.path / "metadata.yaml")

    def _statistics(self) -> Statistics:
        return Statistics(
            message_count=sum(self.counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0, metadata_count=0,
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._t_min if self.counts else 0,
            message_end_time=self._t_max,
            channel_message_counts={c.id: self.counts[t] for t, c in self._channels.items()})

    def _metadata(self) -> dict[str, Any]:
        """rosbag2 ``metadata.yaml`` (version 9), as rosbags writes it."""
        start = self._t_min if any(self.counts.values()) else 0
        duration = {"nanoseconds": max(0, self._t_max - start)}
        n = sum(self.counts.values())
        types = {s.id: s.name for s in self._schemas.values()}
        return {"rosbag2_bagfile_information": {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.file.name],
            "duration": duration,
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": n,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t, "type": types[c.schema_id],
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": [],
                                    "type_description_hash":
                                        self._hashes.get(types[c.schema_id], "")},
                 "message_count": self.counts[t]}
                for t, c in self._channels.items()],
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": self.file.name, "starting_time":
                       {"nanoseconds_since_epoch": start}, "duration": duration,
                       "message_count": n}],
            "custom_data": None,
            "ros_distro": "fd_monitor",
        }}

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_messages(path: str | Path,
                   messages: Iterable[tuple[str, int, int, Sequence[str], Any]],
                   topics: Sequence[str] = ()) -> Path:
    """Write stamped Float64MultiArray messages into a new MCAP bag, in the order given.

    The one writer of simulated bags (:func:`write_bag`, ``simulate``, the bag library).

    Parameters
    ----------
    path : str or pathlib.Path
        Bag folder to create.
    messages : iterable
        ``(topic, timestamp_ns, stamp, labels, values)`` per message.
    topics : sequence of str
        Topics declared first, in this order (with no message or not); the others are
        declared in the order of their first message.
    """
    msgs = list(messages)
    with BagWriter(path) as w:
        for topic in dict.fromkeys([*topics, *(m[0] for m in msgs)]):
            w.add_topic(topic)
        for topic, t, stamp, labels, values in msgs:
            w.write_array(topic, int(stamp), labels, values, int(t))
    return Path(path)


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
    return write_messages(path, ((items[i].topic, t, int(items[i].stamps[j]), items[i].labels,
                                  items[i].values[j]) for t, i, j in events),
                          [a.topic for a in items])


def recover_bag(src: str | Path, dest: str | Path) -> tuple[dict[str, int],
                                                            list[BagDamage]]:
    """Rewrite every readable message of ``src`` into a new, complete bag ``dest``.

    For a bag whose writer died (no summary, no ``metadata.yaml``) or a damaged one.

    Returns
    -------
    (dict, list)
        topic -> messages written, and the damage found in ``src``.
    """
    damage: list[BagDamage] = []
    msgs = _scan(src, damage)
    first = next(msgs, None)
    if first is None:
        raise BagError(f"{src}: no readable message"
                       + (f" ({damage[0]})" if damage else ""))
    with BagWriter(dest) as w:
        for conn, t, data in itertools.chain([first], msgs):
            w.add_topic(conn.topic, conn.msgtype, conn.msgdef)
            w.write_raw(conn.topic, t, data)
    return dict(w.counts), damage

