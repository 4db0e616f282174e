"""rosbag2 MCAP bags: the scanner, one linear pass over an MCAP file that checks every chunk.

:func:`read_raw` is the one bag reader of fd_monitor: it yields ``(topic, msgtype,
timestamp_ns, cdr_bytes)`` in file order, needs neither the summary nor the footer (a writer
that died leaves neither), checks every chunk's CRC before any of its messages is used, and
reports damage by byte position (:class:`BagDamage`) instead of returning changed data; the
rest is read. CRC 0 is "not computed" (the MCAP specification; rosbags writes it): not
damage, said once as ``unchecked``. The pages read are dropped from the process's resident
memory as it goes, so reading a bag does not grow the process by the bag's size.

The writer is :mod:`fd_monitor.wire.bag_writer`; messages and arrays are
:mod:`fd_monitor.wire.bag_reader`.

Why one module of ~520 lines: the scan's damage cases -- a torn chunk, a resync to the next
intact one, a summary without a footer -- are one state machine.
"""

from __future__ import annotations

import itertools
import mmap
import os
import struct
import warnings
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

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

from fd_monitor.model.errors import BagError, FdMonitorWarning
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["MCAP_MAGIC", "BagDamage", "BagDamageWarning", "BagUncheckedWarning", "bag_topics",
           "mcap_file", "read_raw"]

#: The first and last bytes of an MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"


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
#: A record's opcode and length followed by a message's fixed fields.
_RECORD_MESSAGE_HEAD = struct.Struct("<BQHIQQ")


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

    def __init__(self, file: Path, damage: list[BagDamage], flat: bool = False) -> None:
        self.file = file
        self.damage = damage
        self.schemas: dict[int, tuple[str, str]] = {}
        self.channels: dict[int, _Conn] = {}
        self.statistics: Statistics | None = None
        self.messages = 0
        self.unchecked_chunks = 0
        self._parsed: dict[bytes, Any] = {}      # declaration bytes -> parsed record
        #: Messages as ``(topic, msgtype, t, data)`` (:func:`read_raw`), not ``(_Conn, t,
        #: data)`` (:func:`recover_bag` needs the definitions).
        self.flat = flat

    def report(self, offset: int, what: str) -> None:
        self.damage.append(BagDamage(str(self.file), offset, what))

    def __iter__(self) -> Iterator[list[Any]]:
        """The messages in file order, one list per chunk (per-record generator frames were
        the reader's largest cost after decoding)."""
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

    def _scan(self, buf: Any) -> Iterator[list[Any]]:
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
                part = self._chunk(buf, pos, end)
                if part:
                    yield part
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
                    yield self._flat([(conn, m.log_time, m.data)])
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

    def _parse_declaration(self, data: bytes, i: int, j: int) -> Any:
        """:func:`_parse` of a record inside a chunk, remembered by its bytes: a writer
        repeats its schemas and channels in every chunk (a bag cut short stays readable), and
        the strict parse of the same bytes gives the same record."""
        raw = data[i:j]
        rec = self._parsed.get(raw)
        if rec is None:
            rec = _parse(raw, 0, len(raw))
            if len(self._parsed) < 256 and len(raw) < 65536:   # a few small declarations
                self._parsed[raw] = rec
        return rec

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

    def _chunk(self, buf: Any, pos: int, end: int) -> list[Any]:
        """The readable messages of a chunk, in order (none when it is damaged: reported)."""
        try:
            chunk = _parse(buf, pos, end)
        except _PARSE_ERRORS as exc:
            self.report(pos, f"malformed chunk record ({exc}): its messages skipped")
            return []
        span = (f"chunk of messages {chunk.message_start_time * 1e-9:.3f}.."
                f"{chunk.message_end_time * 1e-9:.3f} s")
        try:
            data = _decompress(chunk)
        except _PARSE_ERRORS as exc:
            self.report(pos, f"{span}: cannot decompress ({exc}): its messages skipped")
            return []
        if len(data) != chunk.uncompressed_size:
            self.report(pos, f"{span}: {len(data)} bytes, header says "
                             f"{chunk.uncompressed_size}: its messages skipped")
            return []
        if not chunk.uncompressed_crc:
            self.unchecked_chunks += 1
        elif zlib.crc32(data) != chunk.uncompressed_crc:
            self.report(pos, f"{span}: CRC mismatch (corrupted): its messages skipped")
            return []
        out: list[tuple[int, int, bytes]] = []     # (channel id, log time, data)
        i, n = 0, len(data)
        size, message = _MESSAGE_HEAD.size, Opcode.MESSAGE
        head, hsize = _RECORD_MESSAGE_HEAD, _RECORD_MESSAGE_HEAD.size
        append = out.append
        channel_id = log_time = 0
        try:
            while i < n:
                if i + hsize <= n:      # opcode, length and a message's fixed fields at once
                    op, length, channel_id, _seq, log_time, _pub = head.unpack_from(data, i)
                else:                   # (a record this short is no whole message)
                    op, length = data[i], struct.unpack_from("<Q", data, i + 1)[0]
                j = i + 9 + length
                if j > n:
                    raise ValueError("record runs past the chunk")
                if op == message:       # the hot path: fixed fields, then the data
                    if length < size:
                        raise ValueError("message record shorter than its fixed fields")
                    append((channel_id, log_time, data[i + hsize:j]))
                elif op in _RECORDS:
                    rec = self._parse_declaration(data, i, j)
                    if isinstance(rec, (Schema, Channel)):
                        self._declare(rec)
                i = j
        except _PARSE_ERRORS as exc:
            self.report(pos, f"{span}: malformed record at byte {i} of its content ({exc}): "
                             f"the rest of the chunk skipped")
        channels = self.channels
        ids = {c for c, _t, _p in out}
        if all(c in channels for c in ids):      # the usual case: one lookup per message
            if self.flat:                        # (topic, msgtype, t, data) made here at once
                pairs = {c: (channels[c].topic, channels[c].msgtype) for c in ids}
                found: list[Any] = [pairs[c] + (t, p) for c, t, p in out]
            else:
                found = [(channels[c], t, p) for c, t, p in out]
            self.messages += len(found)
            return found
        return self._flat([(conn, t, p) for c, t, p in out
                           if (conn := self._channel(c, pos)) is not None])

    def _flat(self, part: list[tuple[_Conn, int, bytes]]) -> list[Any]:
        """``part`` as ``(topic, msgtype, t, data)`` when :attr:`flat`."""
        return [(c.topic, c.msgtype, t, d) for c, t, d in part] if self.flat else part


def _scan(path: str | Path, damage: list[BagDamage] | None
          ) -> Iterator[tuple[_Conn, int, bytes]]:
    """Messages of a bag in file order; damage reported to ``damage`` or as warnings."""
    found: list[BagDamage] = [] if damage is None else damage
    scan = _Scan(mcap_file(path), found)
    try:
        for part in scan:
            yield from part
    finally:
        if damage is None:
            for d in found:
                # one location, so Python's default filter says each damage once even when
                # a command reads the bag several times
                warnings.warn(str(d), BagDamageWarning if d.kind == "damage"
                              else BagUncheckedWarning, stacklevel=1)


def _parts(path: str | Path, damage: list[BagDamage] | None
           ) -> Iterator[list[tuple[str, str, int, bytes]]]:
    """:func:`_scan`'s messages one list per chunk, as ``(topic, msgtype, t, data)``."""
    found: list[BagDamage] = [] if damage is None else damage
    try:
        yield from _Scan(mcap_file(path), found, flat=True)
    finally:
        if damage is None:
            for d in found:     # as in _scan (one location: each said once)
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
    if topics is None and msgtype is None:
        # every message: the chunks' lists chained in C (no generator frame per message);
        # as lazy as the generator below (nothing is read before the first next())
        return itertools.chain.from_iterable(_parts(path, damage))
    return _read_raw(path, topics, msgtype, damage)


def _read_raw(path: str | Path, topics: Sequence[str] | None, msgtype: str | None,
              damage: list[BagDamage] | None) -> Iterator[tuple[str, str, int, bytes]]:
    """:func:`read_raw` with a topic or type filter."""
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

