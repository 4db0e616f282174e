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
    return [*good, *bad, stamp_nan, stamp_frac, *good]


def _outcome(fn, msg):
    try:
        d = fn(msg)
    except MessageError as exc:
        return ("error", type(exc).__name__, str(exc))
    return ("ok", d.stamp, d.labels, d.values.tobytes())


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
