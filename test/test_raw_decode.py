"""RawDecoder (serialized messages, the nodes' input path) == decode, result and error;
big-endian bytes go through the fallback deserializer."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
import pytest

from fd_monitor.model.errors import MessageError
from fd_monitor.wire.conversions import RawDecoder, decode, to_msg

LABELS = ("h1", "h2", "h3")


def _plain(values):
    from std_msgs.msg import Float64MultiArray

    return Float64MultiArray(data=[float(v) for v in values])


def _cases():
    good = [to_msg(LABELS, k, [0.1 * k, 0.2, -0.3 * k]) for k in range(5)]
    bad = [
        to_msg(LABELS, 5, [0.1, math.nan, 0.3]),          # NaN value
        to_msg(LABELS, 6, [0.1, math.inf, 0.3]),          # Inf value
        to_msg(("a", "b", "c"), 7, [0.1, 0.2, 0.3]),      # other labels, same length
        to_msg(LABELS[:2], 8, [0.1, 0.2]),                # wrong length
    ]
    stamp_nan = to_msg(LABELS, 9, [0.1, 0.2, 0.3])
    stamp_nan.data[0] = math.nan                          # unreadable stamp, known layout
    stamp_frac = to_msg(LABELS, 9, [0.1, 0.2, 0.3])
    stamp_frac.data[0] = 9.5
    marked = [to_msg(LABELS, k, [0.1 * k, 0.2, -0.3 * k], batch=True) for k in range(10, 13)]
    marked_bad = to_msg(LABELS, 13, [0.1, math.nan, 0.3], batch=True)
    # unmarked, marked, unmarked again: the mark is part of the layout the fast path caches
    return [*good, *bad, stamp_nan, stamp_frac, *good, *marked, marked_bad, *marked, *good]


def _outcome(fn, msg):
    try:
        d = fn(msg)
    except MessageError as exc:
        return ("error", type(exc).__name__, str(exc))
    return ("ok", d.stamp, d.labels, d.values.tobytes(), d.batch)


@pytest.mark.parametrize("options", [dict(labels=LABELS, require_stamp=True),
                                     dict(labels=LABELS, allow_nan=True),
                                     dict(size=3)])
def test_raw_decoder_equals_decode(options, monkeypatch):
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64MultiArray

    dec = RawDecoder(partial(deserialize_message, message_type=Float64MultiArray), "/t",
                     **options)
    msgs = [*_cases(), _plain([1.0, 2.0, 3.0]), _plain([1.0, math.nan, 3.0]),
            _plain([4.0, 5.0, 6.0])]
    for msg in msgs:
        raw = serialize_message(msg)
        assert _outcome(dec.decode, raw) == _outcome(
            lambda m: decode(m, "/t", **options), msg)
    # the fast path is taken: a known layout is read without decode or a deserializer
    dec.decode(serialize_message(to_msg(LABELS, 41, [1.0, 2.0, 3.0])))
    from fd_monitor.wire import conversions

    def boom(*args, **kwargs):
        raise AssertionError("decode called for a known layout")

    monkeypatch.setattr(conversions, "decode", boom)
    dec.fallback = None
    d = dec.decode(serialize_message(to_msg(LABELS, 42, [7.0, 8.0, 9.0])))
    assert d.stamp == 42 and d.labels == LABELS
    np.testing.assert_array_equal(d.values, [7.0, 8.0, 9.0])


def test_big_endian_goes_through_the_fallback():
    from rclpy.serialization import serialize_message

    raw = bytearray(serialize_message(to_msg(LABELS, 3, [1.0, 2.0, 3.0])))
    raw[1] = 0                                  # CDR_BE header: not parsed here
    seen = []

    def fallback(b):
        seen.append(b)
        return to_msg(LABELS, 3, [1.0, 2.0, 3.0])

    d = RawDecoder(fallback, "/t", labels=LABELS).decode(bytes(raw))
    assert seen and d.stamp == 3


def test_the_batch_mark_is_read_by_decode_and_ignored_by_readers_that_do_not_know_it():
    """The batch mark (``layout.dim[1]``, BATCH_LABEL, an (m, 1) layout): decode and the raw
    decoder say so; rosbags deserialises the message and reads the same labels and values
    from ``dim[0]`` and ``data`` (what the offline reader and older decoders read); a
    second dimension with another label is not a mark; ``set_batch_mark`` (replay) sets and
    clears it on serialized bytes, equal to what rclpy serialises, values unchanged."""
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    from fd_monitor.wire.conversions import BATCH_LABEL, set_batch_mark

    marked = to_msg(LABELS, 7, [1.0, 2.0, 3.0], batch=True)
    assert [d.label for d in marked.layout.dim] == [",".join(LABELS), BATCH_LABEL]
    assert (marked.layout.dim[1].size, marked.layout.dim[1].stride) == (1, 1)
    d = decode(marked, "/t", labels=LABELS)
    assert d.batch and d.stamp == 7 and d.labels == LABELS
    assert not decode(to_msg(LABELS, 7, [1.0, 2.0, 3.0]), "/t").batch
    other = to_msg(LABELS, 7, [1.0, 2.0, 3.0])
    dim = MultiArrayDimension()
    dim.label, dim.size, dim.stride = "batch", 1, 1
    other.layout.dim.append(dim)
    assert not decode(other, "/t").batch
    raw = serialize_message(marked)
    ts = get_typestore(Stores.ROS2_JAZZY)
    rb = ts.deserialize_cdr(raw, "std_msgs/msg/Float64MultiArray")
    assert rb.layout.dim[0].label == "h1,h2,h3" and list(rb.data) == [7.0, 1.0, 2.0, 3.0]
    assert decode(rb, "/t").batch
    dec = RawDecoder(partial(deserialize_message, message_type=Float64MultiArray), "/t")
    assert [dec.decode(raw).batch for _ in range(3)] == [True] * 3
    plain_raw = serialize_message(to_msg(LABELS, 7, [1.0, 2.0, 3.0]))

    def fields(b):                   # (CDR padding bytes are not defined: compare fields)
        m = deserialize_message(b, Float64MultiArray)
        return ([(d.label, d.size, d.stride) for d in m.layout.dim], m.layout.data_offset,
                list(m.data))
    assert fields(set_batch_mark(plain_raw, True)) == fields(raw)
    assert fields(set_batch_mark(raw, False)) == fields(plain_raw)
    assert set_batch_mark(raw, True) is raw
    unlabelled = serialize_message(_plain([1.0, 2.0]))
    m = deserialize_message(set_batch_mark(unlabelled, True), Float64MultiArray)
    assert decode(m, "/t").batch and list(m.data) == [1.0, 2.0]
    assert set_batch_mark(b"not cdr", True) == b"not cdr"
