"""rosbag2 MCAP bags of fd_monitor topics: write, read into arrays, list.

Usable without ROS: bags are rosbag2 bags (format version 9, MCAP storage) that rosbags and
rosbag2 read; fd_monitor writes them with the ``mcap`` package's record classes (zstd chunks
with CRCs, flushed at least every :data:`FLUSH_SECONDS` by ``record``) and reads them with
one function, :func:`read_raw`, that checks every chunk, reports damage by byte position
and reads bags whose writer died. Messages are (de)serialised with the rosbags ROS 2 Jazzy
type store; nothing here imports rclpy. Messages on
fd_monitor topics are self-describing Float64MultiArrays (labels in ``layout.dim[0].label``,
the sample stamp in ``data[0]``; see :mod:`fd_monitor.wire.conversions`), so a topic reads
back as arrays::

    arrays = read_bag("run1")["/plant/y"]
    arrays.stamps      # (K,) int64 sample indices k
    arrays.labels      # ("h1", "h2", "h3")
    arrays.values      # (K, 3)
    arrays.receive_ns  # (K,) int64 bag timestamps (receive time when recorded), ns

The CDR bytes written are the bytes rclpy publishes, so ``record``/``replay`` move them
unchanged.

Why one module of ~1050 lines: writer, MCAP scanner, reading and recovery; issue 22 item 3
splits it into writer, scanner and reader, deferred while the bag code was being changed by
other work.
"""

from __future__ import annotations

import itertools
import mmap
import os
import struct
import time
import warnings
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import yaml
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import EndOfFile
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

from fd_monitor.model.errors import BagError, FdMonitorWarning, MessageError, WrongLengthError
from fd_monitor.model.yaml_io import read_yaml
from fd_monitor.wire.conversions import (
    MAX_STAMP,
    ArrivalStamper,
    cdr_shape,
    decode,
    encode_data,
    join_labels,
    parse_cdr,
)
from fd_monitor.wire.topics import FLOAT64_MULTI_ARRAY

__all__ = [
    "CHUNK_BYTES",
    "FLUSH_SECONDS",
    "BagDamage",
    "BagDamageWarning",
    "BagUncheckedWarning",
    "BagWriter",
    "TopicArrays",
    "array_msg",
    "arrays_from",
    "arrays_from_raw",
    "bag_topics",
    "mcap_file",
    "messages_from_raw",
    "read_bag",
    "read_messages",
    "read_raw",
    "recover_bag",
    "serialize_array",
    "write_bag",
    "write_messages",
]


MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Uncompressed bytes per chunk: a damaged chunk loses at most this much (~600 samples of a
#: 3-channel topic), at ~1 % more bytes than 1 MiB chunks.
CHUNK_BYTES = 64 * 1024
#: ``record`` writes a chunk once its oldest message is this old (s).
FLUSH_SECONDS = 0.5


@cache
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _deserialize(raw: bytes, msgtype: str) -> Any:
    """One CDR message -> its fields (a rosbags dataclass, or a
    :class:`~fd_monitor.wire.conversions.CdrFloat64MultiArray` with the same fields and
    values); rosbags' error on bytes that do not decode."""
    if msgtype == FLOAT64_MULTI_ARRAY:
        msg = parse_cdr(raw)
        if msg is not None:
            return msg
    return _typestore().deserialize_cdr(raw, msgtype)


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


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class BagDamage:
    """Something wrong in an MCAP file, found while reading it.

    Attributes
    ----------
    file : str
    offset : int
        Byte position in the file of the record concerned.
    what : str
        One line: what is wrong and what was done (``its messages skipped``, ...).
    """

    file: str
    offset: int
    what: str
    #: ``damage`` (messages lost or changed), or ``unchecked`` (chunks with CRC 0, which the
    #: MCAP specification defines as "not computed": nothing is known to be wrong, bit
    #: errors in them just cannot be detected).
    kind: str = "damage"

    def __str__(self) -> str:
        return f"{self.file}: byte {self.offset}: {self.what}"


class BagDamageWarning(FdMonitorWarning):
    """A bag is damaged or incomplete; what could be read was read (see :class:`BagDamage`)."""


class BagUncheckedWarning(FdMonitorWarning):
    """A bag's chunks carry no CRC (CRC 0, "not computed" in the MCAP specification): not
    damage, but bit errors in them cannot be detected."""


def mcap_file(path: str | Path) -> Path:
    """The ``.mcap`` file of a bag folder (or the file itself).

    A folder without ``metadata.yaml`` (its writer died) is read from its single ``.mcap``.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    if p.is_file():
        return p
    meta = p / "metadata.yaml"
    if meta.is_file():
        try:
            info = read_yaml(meta, BagError)       # the strict reader: size, tags, UTF-8
            files = info["rosbag2_bagfile_information"]["relative_file_paths"]
            if len(files) != 1 or not str(files[0]).endswith(".mcap"):
                raise ValueError(f"expected one .mcap file, got {files}")
            if Path(str(files[0])).name != str(files[0]):
                # rosbag2 lists the bag's own files, by name: a path elsewhere would read
                # another bag's data under this bag's name
                raise ValueError(f"relative_file_paths names {str(files[0])!r}, not a file "
                                 f"of this bag folder")
        except (BagError, OSError, KeyError, TypeError, ValueError) as exc:
            raise BagError(f"{p}: not a readable rosbag2 bag: metadata.yaml: "
                           f"{str(exc).splitlines()[0]}") from None
        f = p / str(files[0])
        if not f.is_file():
            raise BagError(f"{p}: not a readable rosbag2 bag: {f.name} (listed in "
                           f"metadata.yaml) is missing")
        return f
    found = sorted(p.glob("*.mcap"))
    if len(found) != 1:
        raise BagError(f"{p}: not a rosbag2 bag (expected a folder with metadata.yaml or "
                       f"one .mcap file, found {len(found)})")
    return found[0]


_RECORDS: dict[int, Any] = {
    Opcode.HEADER: Header, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
    Opcode.CHUNK: Chunk, Opcode.MESSAGE_INDEX: MessageIndex, Opcode.CHUNK_INDEX: ChunkIndex,
    Opcode.STATISTICS: Statistics, Opcode.DATA_END: DataEnd,
    Opcode.SUMMARY_OFFSET: SummaryOffset, Opcode.FOOTER: Footer,
}
_SKIPPED = {Opcode.ATTACHMENT, Opcode.ATTACHMENT_INDEX, Opcode.METADATA,
            Opcode.METADATA_INDEX}


#: Bytes of a bag read before their pages are dropped from the reader's resident memory.
_RELEASE = 1 << 24


def _release(buf: Any, lo: int, hi: int) -> int:
    """Drop the pages of ``buf[lo:hi]`` (a read-only file mapping, already read: every record
    is copied out of it) from this process's resident memory, so reading a bag does not grow
    the process by the bag's size; the page cache keeps them. Returns the new low mark."""
    top = hi - hi % mmap.PAGESIZE
    advice = getattr(mmap, "MADV_DONTNEED", None)
    if top > lo and advice is not None and hasattr(buf, "madvise"):
        buf.madvise(advice, lo, top - lo)
        return top
    return lo


def _parse(buf: Any, pos: int, end: int) -> Any:
    """The record at ``buf[pos:end]``, strictly: it must write back to the same bytes."""
    op = buf[pos]
    content = bytes(buf[pos + 9:end])
    stream = ReadDataStream(BytesIO(content))
    rec = (Message.read(stream, len(content)) if op == Opcode.MESSAGE
           else _RECORDS[op].read(stream))
    again = RecordBuilder()
    rec.write(again)
    if again.end() != bytes(buf[pos:end]):
        raise ValueError("fields inconsistent with its length")
    return rec


_MESSAGE_HEAD = struct.Struct("<HIQQ")   # channel_id, sequence, log_time, publish_time


def _message_index_ok(buf: Any, pos: int, end: int) -> bool:
    """The MessageIndex record at ``buf[pos:end]`` is one :func:`_parse` accepts: its
    records length is the rest of its content, a whole number of (time, offset) pairs (any
    numbers). Reading uses no index, so the check is all it needs; a record failing it goes
    to :func:`_parse` for the error to report."""
    n = end - pos - 9
    return n >= 6 and (n - 6) % 16 == 0 and struct.unpack_from("<I", buf, pos + 11)[0] == n - 6


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        return bytes(zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size))
    if chunk.compression == "lz4":
        import lz4.frame  # optional: only other writers use it

        return bytes(lz4.frame.decompress(chunk.data))
    if chunk.compression == "":
        return bytes(chunk.data)
    raise ValueError(f"unknown compression {chunk.compression[:20]!r}")


_PARSE_ERRORS = (ValueError, KeyError, EndOfFile, struct.error, UnicodeDecodeError,
                 zstandard.ZstdError, OverflowError, MemoryError, RuntimeError)


@dataclass
class _Conn:
    topic: str
    msgtype: str
    msgdef: str


class _Scan:
    """One linear pass over an MCAP file, record by record, reporting damage.

    Needs neither the summary nor the footer (a crashed writer leaves neither). Every chunk
    with a CRC is checked before any of its messages is used; a damaged chunk is reported
    and skipped, and reading goes on at the next record (or, when the record structure
    itself is damaged, at the next intact chunk found by scanning forward).
    """

    def __init__(self, file: Path, damage: list[BagDamage]) -> None:
        self.file = file
        self.damage = damage
        self.schemas: dict[int, tuple[str, str]] = {}
        self.channels: dict[int, _Conn] = {}
        self.statistics: Statistics | None = None
        self.messages = 0
        self.unchecked_chunks = 0

    def report(self, offset: int, what: str) -> None:
        self.damage.append(BagDamage(str(self.file), offset, what))

    def __iter__(self) -> Iterator[tuple[_Conn, int, bytes]]:
        try:
            with self.file.open("rb") as f:
                size = os.fstat(f.fileno()).st_size
                if size == 0:
                    raise BagError(f"{self.file}: empty file (0 bytes): nothing was written")
                with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
                    yield from self._scan(buf)
        except OSError as exc:
            if isinstance(exc, BagError):
                raise
            raise BagError(f"{self.file}: cannot read: {exc.strerror or exc}") from None

    def _summary(self, buf: Any) -> None:
        """Channels and statistics of the summary, when the footer is intact (CRC checked)."""
        n = len(buf)
        foot = n - 8 - 29
        if foot < 8 or bytes(buf[n - 8:]) != MCAP_MAGIC or buf[foot] != Opcode.FOOTER:
            return
        try:
            footer = _parse(buf, foot, n - 8)
            start = footer.summary_start
            if not 8 <= start <= foot:
                raise ValueError("summary start out of range")
            crc = zlib.crc32(bytes(buf[foot:foot + 25]), zlib.crc32(bytes(buf[start:foot])))
            if footer.summary_crc and crc != footer.summary_crc:
                raise ValueError("summary CRC mismatch")
            pos = start
            while pos < foot:
                end = pos + 9 + struct.unpack_from("<Q", buf, pos + 1)[0]
                if buf[pos] in _RECORDS and end <= foot:
                    rec = _parse(buf, pos, end)
                    if isinstance(rec, Schema):
                        self.schemas.setdefault(rec.id, (rec.name, rec.data.decode()))
                    elif isinstance(rec, Channel) and rec.schema_id in self.schemas:
                        name, msgdef = self.schemas[rec.schema_id]
                        self.channels.setdefault(rec.id, _Conn(rec.topic, name, msgdef))
                    elif isinstance(rec, Statistics):
                        self.statistics = rec
                pos = end
        except _PARSE_ERRORS as exc:
            self.report(foot, f"summary unusable ({exc}); read without it")
            self.statistics = None

    def _scan(self, buf: Any) -> Iterator[tuple[_Conn, int, bytes]]:
        n = len(buf)
        if n < 8 or bytes(buf[:8]) != MCAP_MAGIC:
            raise BagError(f"{self.file}: not an MCAP file (its first bytes are not the MCAP "
                           f"magic)")
        self._summary(buf)
        pos, ended = 8, False
        released = 0
        while pos < n:
            if pos - released >= _RELEASE:
                released = _release(buf, released, pos)
            if n - pos < 9:
                self.report(pos, f"file ends inside a record header ({n - pos} bytes): the "
                                 f"writer stopped here")
                break
            op = buf[pos]
            end = pos + 9 + struct.unpack_from("<Q", buf, pos + 1)[0]
            if end > n:
                if op == Opcode.CHUNK:
                    self.report(pos, f"last chunk incomplete ({n - pos} of {end - pos} "
                                     f"bytes): the writer stopped while writing it")
                    break
                pos = self._resync(buf, pos, f"record (opcode 0x{op:02x}) runs past the end "
                                             f"of the file")
                continue
            if op == Opcode.CHUNK:
                yield from self._chunk(buf, pos, end)
            elif op == Opcode.DATA_END:
                self._data_end(buf, pos, end)
                ended = True
                break
            elif op == Opcode.MESSAGE:
                try:
                    m = _parse(buf, pos, end)
                except _PARSE_ERRORS as exc:
                    pos = self._resync(buf, pos, f"malformed message record ({exc})")
                    continue
                conn = self._channel(m.channel_id, pos)
                if conn is not None:
                    yield conn, m.log_time, m.data
            elif op == Opcode.MESSAGE_INDEX and _message_index_ok(buf, pos, end):
                pass
            elif op in _RECORDS:
                try:
                    rec = _parse(buf, pos, end)
                except _PARSE_ERRORS as exc:
                    pos = self._resync(buf, pos, f"malformed {_RECORDS[op].__name__} record "
                                                 f"({exc})")
                    continue
                if isinstance(rec, (Schema, Channel)):
                    self._declare(rec)
                elif isinstance(rec, Footer):
                    ended = True
                    break
            elif op not in _SKIPPED:
                pos = self._resync(buf, pos, f"unknown record type 0x{op:02x}")
                continue
            pos = end
        if not ended:
            self.report(min(pos, n), "no end of data: the writer did not close the bag "
                                     "(crashed or killed); everything before was read")
        elif not self._ends_with_footer(buf):
            self.report(n, "the file does not end with an MCAP footer and magic: bytes "
                           "appended after the bag, or its end damaged (every message before "
                           "the end of data was read)")
        elif self.statistics is not None and not self.damage:
            if self.statistics.message_count != self.messages:
                self.report(n, f"the summary lists {self.statistics.message_count} messages "
                               f"but {self.messages} were read")
        if self.unchecked_chunks:
            # CRC 0 is "not computed" (MCAP spec; rosbags writes it): a note, not damage
            self.damage.append(BagDamage(
                str(self.file), 8, f"{self.unchecked_chunks} chunk(s) carry no CRC (CRC 0: not "
                                   f"computed by their writer): bit errors in them cannot be "
                                   f"detected (`python -m fd_monitor bag recover` rewrites "
                                   f"the bag with CRCs)", "unchecked"))

    @staticmethod
    def _ends_with_footer(buf: Any) -> bool:
        """The file ends with a footer record and the MCAP magic (nothing appended)."""
        n = len(buf)
        foot = n - 8 - 29
        return (foot >= 8 and bytes(buf[n - 8:]) == MCAP_MAGIC and buf[foot] == Opcode.FOOTER
                and struct.unpack_from("<Q", buf, foot + 1)[0] == 20)

    def _data_end(self, buf: Any, pos: int, end: int) -> None:
        try:
            rec = _parse(buf, pos, end)
        except _PARSE_ERRORS as exc:
            self.report(pos, f"malformed end-of-data record ({exc})")
            return
        crc = 0
        if not self.damage and rec.data_section_crc:
            with memoryview(buf) as view:         # in slices of the mapping: no copy
                for i in range(0, pos, _RELEASE):
                    with view[i:min(i + _RELEASE, pos)] as part:
                        crc = zlib.crc32(part, crc)
                    _release(buf, i, min(i + _RELEASE, pos))
        if not self.damage and rec.data_section_crc and crc != rec.data_section_crc:
            self.report(pos, "data-section CRC mismatch: bytes outside the message chunks "
                             "(indexes, headers) changed; every message read passed its "
                             "chunk CRC")

    def _resync(self, buf: Any, pos: int, why: str) -> int:
        """Skip damaged bytes up to the next intact chunk; return where to go on."""
        q = pos + 1
        while True:
            q = buf.find(bytes([Opcode.CHUNK]), q)
            if q < 0 or q + 9 > len(buf):
                self.report(pos, f"{why}: nothing readable after it ({len(buf) - pos} bytes "
                                 f"skipped)")
                return len(buf) + 1
            end = q + 9 + struct.unpack_from("<Q", buf, q + 1)[0]
            if end <= len(buf) and end - q > 45:
                try:
                    chunk = _parse(buf, q, end)
                    if chunk.uncompressed_crc and \
                            zlib.crc32(_decompress(chunk)) == chunk.uncompressed_crc:
                        self.report(pos, f"{why}: skipped {q - pos} bytes to the next intact "
                                         f"chunk at byte {q}; messages in between are lost")
                        return q
                except _PARSE_ERRORS:
                    pass
            q += 1

    def _declare(self, rec: Schema | Channel) -> None:
        if isinstance(rec, Schema):
            self.schemas[rec.id] = (rec.name, rec.data.decode())
        elif rec.schema_id in self.schemas:
            name, msgdef = self.schemas[rec.schema_id]
            self.channels[rec.id] = _Conn(rec.topic, name, msgdef)

    def _channel(self, channel_id: int, where: int) -> _Conn | None:
        """The channel of a message (counted), or None (reported: the message is skipped)."""
        conn = self.channels.get(channel_id)
        if conn is None:
            self.report(where, f"message of undeclared channel {channel_id} skipped")
            return None
        self.messages += 1
        return conn

    def _chunk(self, buf: Any, pos: int, end: int) -> Iterator[tuple[_Conn, int, bytes]]:
        try:
            chunk = _parse(buf, pos, end)
        except _PARSE_ERRORS as exc:
            self.report(pos, f"malformed chunk record ({exc}): its messages skipped")
            return
        span = (f"chunk of messages {chunk.message_start_time * 1e-9:.3f}.."
                f"{chunk.message_end_time * 1e-9:.3f} s")
        try:
            data = _decompress(chunk)
        except _PARSE_ERRORS as exc:
            self.report(pos, f"{span}: cannot decompress ({exc}): its messages skipped")
            return
        if len(data) != chunk.uncompressed_size:
            self.report(pos, f"{span}: {len(data)} bytes, header says "
                             f"{chunk.uncompressed_size}: its messages skipped")
            return
        if not chunk.uncompressed_crc:
            self.unchecked_chunks += 1
        elif zlib.crc32(data) != chunk.uncompressed_crc:
            self.report(pos, f"{span}: CRC mismatch (corrupted): its messages skipped")
            return
        out: list[tuple[int, int, bytes]] = []     # (channel id, log time, data)
        i = 0
        size, message = _MESSAGE_HEAD.size, Opcode.MESSAGE
        try:
            while i < len(data):
                j = i + 9 + struct.unpack_from("<Q", data, i + 1)[0]
                if j > len(data):
                    raise ValueError("record runs past the chunk")
                op = data[i]
                if op == message:       # the hot path: fixed fields, then the data
                    if j - i - 9 < size:
                        raise ValueError("message record shorter than its fixed fields")
                    channel_id, _seq, log_time, _pub = _MESSAGE_HEAD.unpack_from(data, i + 9)
                    out.append((channel_id, log_time, data[i + 9 + size:j]))
                elif op in _RECORDS:
                    rec = _parse(data, i, j)
                    if isinstance(rec, (Schema, Channel)):
                        self._declare(rec)
                i = j
        except _PARSE_ERRORS as exc:
            self.report(pos, f"{span}: malformed record at byte {i} of its content ({exc}): "
                             f"the rest of the chunk skipped")
        for channel_id, log_time, payload in out:
            conn = self._channel(channel_id, pos)
            if conn is not None:
                yield conn, log_time, payload


def _scan(path: str | Path, damage: list[BagDamage] | None
          ) -> Iterator[tuple[_Conn, int, bytes]]:
    """Messages of a bag in file order; damage reported to ``damage`` or as warnings."""
    found: list[BagDamage] = [] if damage is None else damage
    scan = _Scan(mcap_file(path), found)
    try:
        yield from scan
    finally:
        if damage is None:
            for d in found:
                # one location, so Python's default filter says each damage once even when
                # a command reads the bag several times
                warnings.warn(str(d), BagDamageWarning if d.kind == "damage"
                              else BagUncheckedWarning, stacklevel=1)


def read_raw(path: str | Path, topics: Sequence[str] | None = None, *,
             msgtype: str | None = None, damage: list[BagDamage] | None = None
             ) -> Iterator[tuple[str, str, int, bytes]]:
    """Yield ``(topic, msgtype, timestamp_ns, cdr_bytes)`` in file order: the one bag reader.

    Every other reader (:func:`read_messages`, :func:`read_bag`, :func:`bag_topics`,
    ``replay``, ``analyze``, the library) goes through this function. It reads a bag whose
    writer died (no summary, no ``metadata.yaml``), checks every chunk's CRC, and reports a
    damaged chunk by byte position instead of returning changed data; the rest is read.

    Parameters
    ----------
    path : str or pathlib.Path
        A bag folder, or its ``.mcap`` file.
    topics : sequence of str, optional
        Topics to read; each must be in the bag (checked when the bag has been read).
    msgtype : str, optional
        The type every read topic must have (a topic of another type is an error).
    damage : list, optional
        Collects :class:`BagDamage`; without it, each is a :class:`BagDamageWarning`.

    Raises
    ------
    BagError
        Missing bag, not an MCAP file, a topic missing or of another type.
    """
    want = None if topics is None else set(topics)
    seen: set[str] = set()
    for conn, t, data in _scan(path, damage):
        seen.add(conn.topic)
        if want is not None and conn.topic not in want:
            continue
        if msgtype is not None and conn.msgtype != msgtype:
            raise BagError(f"{path}: {conn.topic} is {conn.msgtype}, not {msgtype}")
        yield conn.topic, conn.msgtype, t, data
    missing = sorted((want or set()) - seen)
    if missing:
        raise BagError(f"{path}: no topic {', '.join(missing)} in the bag (topics: "
                       f"{', '.join(sorted(seen)) or 'none'})")


def bag_topics(path: str | Path) -> dict[str, tuple[str, int]]:
    """topic -> (message type, number of readable messages) of a bag."""
    out: dict[str, tuple[str, int]] = {}
    for topic, msgtype, _t, _data in read_raw(path):
        out[topic] = (msgtype, out.get(topic, (msgtype, 0))[1] + 1)
    return out


def read_messages(path: str | Path, topics: Sequence[str] | None = None, *,
                  msgtype: str | None = None) -> Iterator[tuple[str, int, Any]]:
    """Yield ``(topic, timestamp_ns, message)`` in file order (rosbags dataclasses).

    ``msgtype``: see :func:`read_raw`.
    """
    yield from messages_from_raw(path, read_raw(path, topics, msgtype=msgtype))


def messages_from_raw(path: str | Path, records: Iterable[tuple[str, str, int, bytes]]
                      ) -> Iterator[tuple[str, int, Any]]:
    """:func:`read_messages` of records already read with :func:`read_raw` (``path`` names
    the bag in errors)."""
    for topic, ty, t, raw in records:
        try:
            msg = _deserialize(raw, ty)
        except Exception as exc:  # rosbags raises assorted errors on CDR of another type
            raise BagError(f"{path}: {topic} at {t * 1e-9:.3f} s: not a valid {ty} "
                           f"({type(exc).__name__})") from None
        yield topic, t, msg


def read_bag(path: str | Path, topics: Sequence[str] | None = None
             ) -> dict[str, TopicArrays]:
    """Read Float64MultiArray topics of a bag into :class:`TopicArrays`.

    Parameters
    ----------
    path : str or pathlib.Path
        The bag folder.
    topics : sequence of str, optional
        Topics to read (each must be in the bag and a Float64MultiArray); default every
        Float64MultiArray topic.

    Raises
    ------
    BagError
        Missing bag, not a bag, missing topic, or a malformed message (topic and stamp named).

    Examples
    --------
    >>> b = read_bag("bags/three_tank_bias_h1")
    >>> b["/plant/y"].labels, b["/plant/y"].values.shape
    (('h1', 'h2', 'h3'), (2500, 3))
    """
    return arrays_from_raw(path, read_raw(path, topics,
                                          msgtype=FLOAT64_MULTI_ARRAY if topics else None))


def arrays_from_raw(path: str | Path, records: Iterable[tuple[str, str, int, bytes]]
                    ) -> dict[str, TopicArrays]:
    """:func:`read_bag` of records already read with :func:`read_raw` (``path`` names the
    bag in errors); records of other types than Float64MultiArray are skipped."""
    recs = [r for r in records if r[1] == FLOAT64_MULTI_ARRAY]
    same = _arrays_of_one_layout(recs)
    return same if same is not None else _arrays_message_by_message(path, recs)


def _arrays_message_by_message(path: str | Path,
                               records: Sequence[tuple[str, str, int, bytes]]
                               ) -> dict[str, TopicArrays]:
    """:func:`arrays_from_raw` of Float64MultiArray records, each message decoded and
    checked on its own (a bad one named in the BagError)."""
    acc: dict[str, tuple[list[int], list[np.ndarray], list[int]]] = {}
    labels: dict[str, tuple[str, ...]] = {}
    stampers: dict[str, ArrivalStamper] = {}
    order: list[str] = []
    for topic, ty, t, raw in records:
        if topic not in acc:
            order.append(topic)
        ks, vs, ts = acc.setdefault(topic, ([], [], []))
        first = labels.get(topic)
        try:
            d = stampers.setdefault(topic, ArrivalStamper()).stamp(
                decode(_deserialize(raw, ty), topic, labels=first, allow_nan=True,
                       allow_inf=True))
        except MessageError as exc:
            raise BagError(f"{path}: {exc}") from None
        if first is None:
            # Unlabelled (a user's driver): name the channels by position.
            labels[topic] = d.labels or tuple(str(i) for i in range(d.values.size))
        ks.append(int(d.stamp or 0))
        vs.append(d.values)
        ts.append(int(t))
    out: dict[str, TopicArrays] = {}
    for topic in order:
        ks, vs, ts = acc[topic]
        out[topic] = TopicArrays(topic, labels[topic], np.asarray(ks, dtype=np.int64),
                                 np.vstack(vs), np.asarray(ts, dtype=np.int64))
    return out


def _arrays_of_one_layout(records: Sequence[tuple[str, str, int, bytes]]
                          ) -> dict[str, TopicArrays] | None:
    """:func:`arrays_from_raw` of Float64MultiArray records when, per topic, every message
    has the length and the bytes before its data (labels, sizes, offset) of the topic's
    first message -- a bag fd_monitor wrote: the first message is decoded (and checked) as
    usual, the data of all as one array, the stamps checked as :func:`decode` checks them.
    None otherwise (the message-by-message loop then reads the bag and names the bad
    message)."""
    topics: dict[str, list[tuple[int, bytes]]] = {}
    for topic, _ty, t, raw in records:
        topics.setdefault(topic, []).append((t, bytes(raw)))
    out: dict[str, TopicArrays] = {}
    for topic, msgs in topics.items():
        raw0 = msgs[0][1]
        shape = cdr_shape(raw0)
        if shape is None:
            return None
        head, layout, start, size = shape
        if any(len(raw) != len(raw0) or not raw.startswith(head) for _t, raw in msgs):
            return None
        try:
            first = decode(parse_cdr(raw0), topic, allow_nan=True, allow_inf=True)
        except MessageError:
            return None
        block = np.frombuffer(b"".join(raw for _t, raw in msgs), np.uint8)
        data = block.reshape(len(msgs), -1)[:, start:start + 8 * size].copy().view("<f8")
        offset = layout.data_offset         # 0 or 1: the first message decoded
        if offset:
            s = data[:, 0]
            if not np.all((s >= 0) & (s < MAX_STAMP) & (s == np.floor(s))):  # NaN: False
                return None
            stamps = s.astype(np.int64)
        else:
            stamps = np.arange(len(msgs), dtype=np.int64)     # ArrivalStamper's numbers
        out[topic] = TopicArrays(
            topic, first.labels or tuple(str(i) for i in range(size - offset)), stamps,
            np.ascontiguousarray(data[:, offset:], np.float64),
            np.array([t for t, _r in msgs], np.int64))
    return out


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
