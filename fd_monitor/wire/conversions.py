"""Conversions between fd_monitor's self-describing Float64MultiArray messages and arrays.

Message convention (DESIGN.md, "Topics")::

    layout.dim[0].label  = "h1,h2,h3"      # channel names, comma-separated
    layout.dim[0].size   = 3               # number of values
    layout.dim[0].stride = 3
    layout.data_offset   = 1               # the stamp is the padding element in front
    data = [k, v_0, v_1, v_2]              # k: sample index (an integer stored as float)

A sender whose stream is a *batch* -- recorded or simulated data whose every sample must be
processed, however late (``replay``, ``plant_sim`` flat out, the chain nodes relaying such a
sample) -- marks each message with a second dimension (:data:`BATCH_LABEL`)::

    layout.dim[1].label  = "fd_monitor/batch"
    layout.dim[1].size   = 1               # a trailing singleton: the data is an (m, 1) array
    layout.dim[1].stride = 1

A node more than ``max_lag`` s behind sheds an unmarked (live) backlog but processes a marked
one completely (:mod:`fd_monitor.wire.join`). The mark is a valid ``MultiArrayLayout`` (an m x 1
matrix: ``dim[0].stride = m = dim[0].size x dim[1].size``), so readers that do not know it --
rosbags, the offline bag reader, older fd_monitor decoders (they read ``dim[0]`` only), a
user's tools -- read the same labels and values; it costs nothing per message on the raw
decoder's fast path (it is part of the layout bytes, cached once per layout).

A plain Float64MultiArray from a user's driver (``data_offset = 0``, possibly no ``dim``) is
accepted where a stamp is not required: :func:`decode` returns ``stamp=None`` and the node
stamps it on arrival with a per-topic :class:`ArrivalStamper`.

Pure functions over duck-typed messages: the same code decodes rclpy messages and the
dataclasses ``rosbags`` deserialises, so this module imports no ROS package at import time
(``fd_monitor.wire.bag_reader`` uses it offline). :func:`to_msg` imports ``std_msgs`` when called.

Why one module of ~550 lines: the message convention in one place -- building a message,
decoding one (checked), reading its CDR bytes without a type store (the nodes' and the bag
reader's fast path) and setting the batch mark on those bytes must agree field for field,
and the tests compare them with each other (``test/test_raw_decode.py``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from fd_monitor.model.errors import MessageError, NonFiniteError, WrongLengthError

__all__ = [
    "BATCH_LABEL",
    "STAMP_OFFSET",
    "MAX_LABEL_CHARS",
    "MAX_STAMP",
    "ArrivalStamper",
    "Decoded",
    "decode",
    "encode_data",
    "is_batch",
    "set_batch_mark",
    "join_labels",
    "readable_stamp",
    "CdrDimension",
    "CdrFloat64MultiArray",
    "CdrLayout",
    "RawDecoder",
    "cdr_shape",
    "parse_cdr",
    "split_labels",
    "to_msg",
]

#: ``layout.data_offset`` of a stamped message: one padding element, the stamp.
STAMP_OFFSET = 1
#: ``layout.dim[1].label`` of a message whose stream is a batch (every sample to be
#: processed; see the module docstring). Namespaced: a user's (m, 1) array is not marked.
BATCH_LABEL = "fd_monitor/batch"
#: Largest stamp a float64 holds exactly.
MAX_STAMP = 2**53
#: Longest ``layout.dim[0].label`` accepted (characters; a message with a longer one is
#: refused): 16 KiB names hundreds of channels. Unbounded, every distinct label a sender
#: invents was kept by the caches below (1 MB labels grew a node by 2.9 GB, issue 26).
MAX_LABEL_CHARS = 16_384
#: Bytes of label text the label cache and the CDR layout cache hold at most (each is
#: emptied when a new entry would pass it: a topic has one layout, so only a sender that
#: invents layouts refills it).
_CACHE_BYTES = 1 << 20


def join_labels(labels: Sequence[str]) -> str:
    """``("h1", "h2")`` -> ``"h1,h2"``; a label may not contain a comma."""
    for lab in labels:
        if "," in lab:
            raise MessageError(f"channel name {lab!r} contains a comma")
    return ",".join(labels)


#: label text -> its split, bounded by bytes (:data:`_CACHE_BYTES`), not by entries.
_LABELS: dict[str, tuple[str, ...]] = {}
_labels_bytes = 0


def split_labels(text: str) -> tuple[str, ...]:
    """``"h1,h2"`` -> ``("h1", "h2")``; ``""`` -> ``()``.

    Cached (every message of a topic carries the same labels) within :data:`_CACHE_BYTES`;
    a text longer than :data:`MAX_LABEL_CHARS` is split but never cached (:func:`decode`
    refuses such a message before it gets here).
    """
    global _labels_bytes
    got = _LABELS.get(text)
    if got is not None:
        return got
    got = tuple(s.strip() for s in text.split(",")) if text.strip() else ()
    if len(text) <= MAX_LABEL_CHARS:
        if _labels_bytes + len(text) > _CACHE_BYTES:
            _LABELS.clear()
            _labels_bytes = 0
        _LABELS[text] = got
        _labels_bytes += len(text)
    return got


def encode_data(stamp: int, values: Any) -> list[float]:
    """The ``data`` field of a stamped message: ``[stamp, *values]``.

    Parameters
    ----------
    stamp : int
        Sample index k, ``0 <= k < 2**53``.
    values : array_like
        (m,) finite values.
    """
    k = int(stamp)
    if not 0 <= k < MAX_STAMP:
        raise MessageError(f"stamp {stamp!r} out of range [0, 2**53)")
    v = np.asarray(values, dtype=float).reshape(-1)
    return [float(k), *v.tolist()]


def to_msg(labels: Sequence[str], stamp: int, values: Any, msg_type: Any = None,
           batch: bool = False) -> Any:
    """Build a stamped, labelled Float64MultiArray.

    Parameters
    ----------
    labels : sequence of str
        (m,) channel names.
    stamp : int
        Sample index k.
    values : array_like
        (m,) values.
    msg_type : type, optional
        The message class and its layout classes' owner; default ``std_msgs.msg`` (rclpy).
        ``fd_monitor.wire.bag_reader`` passes the ``rosbags`` classes.
    batch : bool
        Mark the message as part of a batch (``layout.dim[1]``, :data:`BATCH_LABEL`): a
        node behind by more than ``max_lag`` processes it however late (rclpy messages).
    """
    data = encode_data(stamp, values)
    if len(data) - 1 != len(labels):
        raise WrongLengthError(f"{len(labels)} labels for {len(data) - 1} values")
    if msg_type is None:
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        msg = Float64MultiArray()
        dim = MultiArrayDimension()
        dim.label = join_labels(labels)
        dim.size = len(labels)
        dim.stride = len(labels)
        msg.layout.dim = [dim]
        if batch:
            mark = MultiArrayDimension()
            mark.label, mark.size, mark.stride = BATCH_LABEL, 1, 1
            msg.layout.dim.append(mark)
        msg.layout.data_offset = STAMP_OFFSET
        msg.data = data
        return msg
    return msg_type(labels, data)


def readable_stamp(msg: Any) -> int | None:
    """The stamp of a message that may not decode, when it is readable; else None.

    Readable: ``layout.data_offset == 1`` and ``data[0]`` a finite integer in
    ``[0, 2**53)``. Lets a node tell which sample a rejected message (NaN value, wrong
    length) was for.
    """
    try:
        if int(msg.layout.data_offset) != STAMP_OFFSET or len(msg.data) == 0:
            return None
        s = float(msg.data[0])
    except (AttributeError, TypeError, ValueError):
        return None
    if not math.isfinite(s) or s != int(s) or not 0 <= s < MAX_STAMP:
        return None
    return int(s)


class Decoded(NamedTuple):
    """A decoded message (a named tuple: one is made per message, and a frozen dataclass
    costs more to create than the raw decoder's whole fast path otherwise).

    Attributes
    ----------
    stamp : int or None
        In-band sample index, None for a plain (unstamped) message.
    labels : tuple of str
        Channel names (the expected ones when the message carries none).
    values : numpy.ndarray
        (m,) finite float values.
    batch : bool
        The message carries the batch mark (:data:`BATCH_LABEL`).
    """

    stamp: int | None
    labels: tuple[str, ...]
    values: np.ndarray
    batch: bool = False


def is_batch(dims: Sequence[Any]) -> bool:
    """Whether a message's ``layout.dim`` carries the batch mark (:data:`BATCH_LABEL` in
    ``dim[1]``); any other second dimension is ignored, as before."""
    return len(dims) > 1 and str(dims[1].label) == BATCH_LABEL


def decode(msg: Any, topic: str = "?", *, labels: Sequence[str] | None = None,
           size: int | None = None, require_stamp: bool = False,
           allow_nan: bool = False, allow_inf: bool = False) -> Decoded:
    """Validate and decode a Float64MultiArray.

    Parameters
    ----------
    msg : Float64MultiArray
        An rclpy message or a rosbags dataclass (duck-typed: ``layout.dim``,
        ``layout.data_offset``, ``data``).
    topic : str
        For error messages.
    labels : sequence of str, optional
        Expected channel names; a message with other labels is refused (a message without
        labels is accepted and given these).
    size : int, optional
        Expected number of values (default ``len(labels)`` when labels are given).
    require_stamp : bool
        Refuse an unstamped message (``data_offset = 0``).
    allow_nan : bool
        Accept NaN values (``/fd/threshold_override``: NaN = no override).
    allow_inf : bool
        Accept +-inf values (a recorded ``/fd/threshold``: +inf = no threshold in force).

    Raises
    ------
    MessageError
        One line naming the topic, the stamp when known, and what is wrong.
    """
    data = np.asarray(msg.data, dtype=float).reshape(-1)
    offset = int(msg.layout.data_offset)
    where = topic
    if offset not in (0, STAMP_OFFSET):
        raise MessageError(f"{where}: layout.data_offset {offset}: expected 0 (no stamp) or "
                           f"{STAMP_OFFSET} (stamp in data[0])")
    stamp: int | None = None
    if offset == STAMP_OFFSET:
        if data.size < 1:
            raise MessageError(f"{where}: data_offset 1 but data is empty (no stamp)")
        s = float(data[0])
        if not math.isfinite(s) or s < 0 or s != math.floor(s) or s >= MAX_STAMP:
            raise MessageError(f"{where}: stamp data[0] = {s!r}: expected an integer >= 0")
        stamp = int(s)
        where = f"{topic} stamp {stamp}"
    elif require_stamp:
        raise MessageError(f"{where}: missing stamp (layout.data_offset 0; fd_monitor topics "
                           f"carry the sample index in data[0] with data_offset 1)")
    values = data[offset:]
    dims = list(msg.layout.dim)
    got_labels: tuple[str, ...] = ()
    if dims:
        text = str(dims[0].label)
        if len(text) > MAX_LABEL_CHARS:
            raise MessageError(f"{where}: layout.dim[0].label of {len(text)} characters: "
                               f"longer than {MAX_LABEL_CHARS} (channel names, "
                               f"comma-separated)")
        got_labels = split_labels(text)
        if int(dims[0].size) != values.size:
            raise WrongLengthError(f"{where}: layout.dim[0].size {int(dims[0].size)} but "
                               f"{values.size} values")
        if got_labels and len(got_labels) != values.size:
            raise WrongLengthError(f"{where}: {len(got_labels)} labels for {values.size} "
                                   f"values")
    expected = tuple(labels) if labels is not None else None
    n = size if size is not None else (len(expected) if expected is not None else None)
    if n is not None and values.size != n:
        listed = f" ({','.join(expected)})" if expected else ""
        raise WrongLengthError(f"{where}: wrong length: {values.size} values, expected "
                               f"{n}{listed}")
    if expected is not None and got_labels and got_labels != expected:
        raise MessageError(f"{where}: channels {','.join(got_labels)}: expected "
                           f"{','.join(expected)}")
    # one array operation on the data path (neither allowed), none when both are
    bad = (~np.isfinite(values) if not (allow_nan or allow_inf)
           else np.isinf(values) if allow_nan and not allow_inf
           else np.isnan(values) if allow_inf and not allow_nan
           else None)
    if bad is not None and bad.any():
        i = int(np.flatnonzero(bad)[0])
        names = got_labels or expected or ()
        name = names[i] if i < len(names) else f"#{i}"
        raise NonFiniteError(f"{where}: value {name} is {float(values[i])!r}: expected finite "
                             f"numbers")
    return Decoded(stamp, got_labels or (expected or ()), values.copy(), is_batch(dims))


# -- serialized (CDR) Float64MultiArray, without a type store ---------------------------------

class CdrDimension(NamedTuple):
    """``std_msgs/msg/MultiArrayDimension`` as :func:`parse_cdr` returns it."""

    label: str
    size: int
    stride: int


class CdrLayout(NamedTuple):
    """``std_msgs/msg/MultiArrayLayout`` as :func:`parse_cdr` returns it (``dim`` a
    tuple: one layout is shared by the messages that have the same bytes before the data)."""

    dim: tuple[CdrDimension, ...]
    data_offset: int


class CdrFloat64MultiArray(NamedTuple):
    """``std_msgs/msg/Float64MultiArray`` as :func:`parse_cdr` returns it (the fields of
    the rosbags dataclass; ``data`` a read-only float64 view of the bytes, as rosbags')."""

    layout: CdrLayout
    data: np.ndarray


_U32 = struct.Struct("<I").unpack_from
_U32X2 = struct.Struct("<II").unpack_from
#: Message length -> (the bytes before the data, layout, data start, data size) of messages
#: of that length decoded last: a message of the same length with the same bytes before its
#: data parses the same way, so only its data is read (the messages of a topic share their
#: header bytes: labels, sizes, offset; /plant/u and /plant/y of three_tank share a length).
_CDR_SHAPES: dict[int, list[tuple[bytes, CdrLayout, int, int]]] = {}
_cdr_bytes = 0


def cdr_shape(raw: bytes) -> tuple[bytes, CdrLayout, int, int] | None:
    """Little-endian CDR bytes of a Float64MultiArray -> (the bytes before its data, its
    layout, where its data starts, how many float64 it has), without the type store.

    The rosbags Jazzy deserialiser's steps and checks, written out for this one type: the
    offline reader decodes thousands of these per bag, and loading the type store costs more
    than reading a bag. None for anything that is not a well-formed little-endian message
    (big-endian, truncated, a bad count or string, more than 3 trailing bytes): the caller
    then asks rosbags (:mod:`fd_monitor.wire.bag_reader`) or rclpy, which gives the canonical error.
    Positions are counted from the end of the 4-byte encapsulation header, as CDR aligns them.
    """
    n = len(raw)
    for shape in _CDR_SHAPES.get(n, ()):
        if raw.startswith(shape[0]):
            return shape
    if raw[:2] != b"\x00\x01":
        return None
    n -= 4
    try:
        count, = _U32(raw, 4)
        pos = 4
        if pos + count > n:                        # rosbags: check_sequence(minimum 1)
            return None
        dims = []
        for _ in range(count):
            pos = (pos + 3) & -4
            length, = _U32(raw, 4 + pos)
            end = pos + 4 + length
            if length < 1 or end > n or raw[3 + end] != 0:      # rosbags: check_string
                return None
            if length > MAX_LABEL_CHARS + 1:
                return None      # not cached: the caller's decode refuses it in one line
            label = raw[8 + pos:3 + end].decode()
            pos = (end + 3) & -4
            size, stride = _U32X2(raw, 4 + pos)
            pos += 8
            dims.append(CdrDimension(label, size, stride))
        offset, size = _U32X2(raw, 4 + pos)
        pos += 8
        if pos + 8 * size > n:                     # rosbags: check_sequence(minimum 8)
            return None
        if size:
            pos = (pos + 7) & -8
            if pos + 8 * size > n:                 # rosbags: numpy.frombuffer's ValueError
                return None
    except (struct.error, UnicodeDecodeError):
        return None
    if pos + 8 * size + 7 < n + 4:                 # rosbags: "CDR message size mismatch"
        return None
    shape = (raw[:4 + pos], CdrLayout(tuple(dims), offset), 4 + pos, size)
    global _cdr_bytes
    if len(_CDR_SHAPES) >= 256 or _cdr_bytes + 2 * pos > _CACHE_BYTES:
        # bounded (entries and bytes): ever new layouts only parse every message
        _CDR_SHAPES.clear()
        _cdr_bytes = 0
    _cdr_bytes += 2 * pos                   # the prefix bytes and the label text
    shapes = _CDR_SHAPES.setdefault(n + 4, [])
    if len(shapes) >= 8:
        del shapes[0]
    shapes.append(shape)
    return shape


def parse_cdr(raw: bytes) -> CdrFloat64MultiArray | None:
    """:func:`cdr_shape` and the data: the message's fields (None: see there)."""
    raw = bytes(raw)
    shape = cdr_shape(raw)
    if shape is None:
        return None
    return CdrFloat64MultiArray(shape[1], np.frombuffer(raw, "<f8", shape[3], shape[2]))


def _cdr_prefix(dims: Sequence[CdrDimension], data_offset: int, size: int) -> bytes:
    """Little-endian CDR of a Float64MultiArray up to its data (encapsulation header,
    layout, data length, the padding before the first float64)."""
    out = bytearray(struct.pack("<I", len(dims)))
    for d in dims:
        text = d.label.encode() + b"\0"
        out += b"\0" * (-len(out) % 4) + struct.pack("<I", len(text)) + text
        out += b"\0" * (-len(out) % 4) + struct.pack("<II", d.size, d.stride)
    out += struct.pack("<II", data_offset, size)
    if size:
        out += b"\0" * (-len(out) % 8)
    return b"\x00\x01\x00\x00" + bytes(out)


#: (the bytes before the data, batch) -> the same message's bytes before the data with the
#: batch mark set or cleared (a topic has one layout: one entry per topic and mark).
_MARKED: dict[tuple[bytes, bool], bytes] = {}


def set_batch_mark(raw: bytes, batch: bool) -> bytes:
    """Serialized (little-endian CDR) Float64MultiArray ``raw`` with the batch mark
    (:data:`BATCH_LABEL` in ``layout.dim[1]``) set or cleared; labels, offset and values
    unchanged. ``raw`` itself when it already says so, or when it is not a message
    :func:`cdr_shape` parses (another type, big-endian: published as it is).

    ``replay`` sets the mark on what it publishes (a recorded stream is a batch) and clears
    it with ``--live``: the bytes of a recorded message are otherwise kept as recorded.
    """
    shape = cdr_shape(raw)
    if shape is None:
        return raw
    prefix, layout, start, size = shape
    if is_batch(layout.dim) == batch:
        return raw
    new = _MARKED.get((prefix, batch))
    if new is None:
        dims = list(layout.dim)
        if batch:
            first = dims[0] if dims else CdrDimension("", size - layout.data_offset,
                                                      size - layout.data_offset)
            dims = [first, CdrDimension(BATCH_LABEL, 1, 1), *dims[1:]]
        else:
            del dims[1]
        new = _cdr_prefix(dims, layout.data_offset, size)
        if len(_MARKED) >= 256:
            _MARKED.clear()
        _MARKED[(prefix, batch)] = new
    return new + bytes(raw[start:start + 8 * size])


class RawDecoder:
    """:func:`decode` for serialized (CDR) Float64MultiArray messages of one input, fast.

    Every message is parsed by :func:`cdr_shape` (the bytes before the values are parsed
    once per layout and cached). The first message of a layout goes through :func:`decode`
    with every check; a later message of the same layout (same cached shape) has the same
    labels, stamp offset and length, so only its values are read (one buffer view, no message
    object) and checked: stamp an integer in ``[0, 2**53)``, values finite (as the
    ``allow_*`` flags say). Anything else -- another layout, a bad value, bytes
    :func:`cdr_shape` does not parse -- goes through :func:`decode`, so errors and results
    are :func:`decode`'s, bit for bit (``test/test_raw_decode.py``).

    Parameters
    ----------
    fallback : callable
        ``bytes -> message`` for bytes :func:`cdr_shape` does not parse (big-endian CDR):
        rclpy's ``deserialize_message`` bound to the type, which gives the canonical error.
    topic : str
    **options
        :func:`decode`'s keyword arguments (labels, size, require_stamp, allow_nan, allow_inf).
    """

    def __init__(self, fallback: Any, topic: str = "?", **options: Any) -> None:
        self.fallback, self.topic, self.options = fallback, topic, options
        allow_nan, allow_inf = options.get("allow_nan", False), options.get("allow_inf", False)
        # the value check of decode, as one array operation (None: every value is allowed)
        self._bad = (None if allow_nan and allow_inf else np.isinf if allow_nan
                     else np.isnan if allow_inf else None)
        self._finite_only = not (allow_nan or allow_inf)
        #: the layout :func:`decode` accepted last (a cached :func:`cdr_shape` object), stamped,
        #: labels, the unpacker of its values, the batch mark (part of the layout bytes)
        self._known: tuple[CdrLayout, bool, tuple[str, ...], Any, bool] | None = None

    def message(self, raw: bytes) -> Any:
        """The message's fields (for the error path: :func:`readable_stamp`)."""
        msg = parse_cdr(raw)
        return msg if msg is not None else self.fallback(raw)

    def decode(self, raw: bytes) -> Decoded:
        """Decode one serialized message (raises :class:`MessageError` as :func:`decode`)."""
        shape = cdr_shape(raw)
        known = self._known
        if shape is not None and known is not None and shape[1] is known[0]:
            # the values as Python floats in one struct call (the same float64 bits as a
            # buffer view): a node at 100 Hz runs this cold, where each numpy call costs
            # several microseconds
            data = known[3](raw, shape[2])
            ok, stamp, values = True, None, data
            if known[1]:
                s = data[0]
                ok = 0.0 <= s < MAX_STAMP and s == math.floor(s)      # NaN: False
                stamp = int(s) if ok else None
                values = data[1:]
            if ok and (not all(map(math.isfinite, values)) if self._finite_only
                       else self._bad is not None and self._bad(np.array(values)).any()):
                ok = False
            if ok:
                return Decoded(stamp, known[2], np.array(values, dtype=np.float64), known[4])
        d = decode(self.message(raw), self.topic, **self.options)
        if shape is not None:
            self._known = (shape[1], d.stamp is not None, d.labels,
                           struct.Struct(f"<{shape[3]}d").unpack_from, d.batch)
        return d


class ArrivalStamper:
    """Per-topic counter stamping plain messages on arrival (0, 1, 2, ...).

    A node keeps one per input topic, so the k-th plain message of each topic gets stamp k.
    """

    def __init__(self) -> None:
        self.next = 0

    def stamp(self, decoded: Decoded) -> Decoded:
        """Return ``decoded`` with its stamp, or the next counter value if it has none."""
        if decoded.stamp is not None:
            return decoded
        out = Decoded(self.next, decoded.labels, decoded.values, decoded.batch)
        self.next += 1
        return out
