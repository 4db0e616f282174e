"""rosbag2 MCAP bags of fd_monitor topics, read: messages and arrays.

Every reader here goes through :func:`fd_monitor.wire.bag_scanner.read_raw` (every chunk's CRC
checked, damage reported). Messages are deserialised with the rosbags ROS 2 Jazzy type store
(a Float64MultiArray by :func:`~fd_monitor.wire.conversions.parse_cdr`, without it); nothing
here imports rclpy. Messages on fd_monitor topics are self-describing Float64MultiArrays
(labels in ``layout.dim[0].label``, the sample stamp in ``data[0]``; see
:mod:`fd_monitor.wire.conversions`), so a topic reads back as arrays::

    arrays = read_bag("run1")["/plant/y"]
    arrays.stamps      # (K,) int64 sample indices k
    arrays.labels      # ("h1", "h2", "h3")
    arrays.values      # (K, 3)
    arrays.receive_ns  # (K,) int64 bag timestamps (receive time when recorded), ns

The writer is :mod:`fd_monitor.wire.bag_writer`, the scanner
:mod:`fd_monitor.wire.bag_scanner`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.model.errors import BagError, MessageError
from fd_monitor.wire.bag_scanner import read_raw
from fd_monitor.wire.conversions import (
    MAX_STAMP,
    ArrivalStamper,
    cdr_shape,
    decode,
    parse_cdr,
)
from fd_monitor.wire.topics import FLOAT64_MULTI_ARRAY

__all__ = ["TopicArrays", "arrays_from", "arrays_from_raw", "messages_from_raw", "read_bag",
           "read_messages"]


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
    topics: dict[str, tuple[list[int], list[bytes]]] = {}
    if records and len({r[0] for r in records}) == 1:    # one topic: no grouping
        topics[records[0][0]] = ([r[2] for r in records], [bytes(r[3]) for r in records])
    else:
        for topic, _ty, t, raw in records:
            ts, raws = topics.setdefault(topic, ([], []))
            ts.append(t)
            raws.append(bytes(raw))
    out: dict[str, TopicArrays] = {}
    for topic, (times, msgs) in topics.items():
        raw0 = msgs[0]
        shape = cdr_shape(raw0)
        if shape is None:
            return None
        head, layout, start, size = shape
        n0 = len(raw0)
        if any(len(raw) != n0 for raw in msgs) or not all(
                [raw.startswith(head) for raw in msgs]):
            return None
        try:
            first = decode(parse_cdr(raw0), topic, allow_nan=True, allow_inf=True)
        except MessageError:
            return None
        block = np.frombuffer(b"".join(msgs), np.uint8)
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
            np.array(times, np.int64))
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
