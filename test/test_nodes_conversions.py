"""Message conversions: stamped, labelled Float64MultiArray <-> arrays, and bad messages."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fd_monitor.model.errors import MessageError
from fd_monitor.wire.conversions import (
    ArrivalStamper,
    decode,
    encode_data,
    join_labels,
    split_labels,
)

LABELS = ("h1", "h2", "h3")


def plain(data, offset=0, label=None, size=None):
    """A duck-typed Float64MultiArray (what rosbags and rclpy both look like)."""
    dims = [] if label is None else [SimpleNamespace(label=label, size=size, stride=size)]
    return SimpleNamespace(layout=SimpleNamespace(dim=dims, data_offset=offset), data=data)


def test_rclpy_message_round_trip():
    pytest.importorskip("std_msgs")
    from fd_monitor.wire.conversions import to_msg

    msg = to_msg(LABELS, 42, [0.4, 0.2, 0.3])
    assert msg.layout.data_offset == 1
    assert msg.layout.dim[0].label == "h1,h2,h3" and msg.layout.dim[0].size == 3
    assert list(msg.data) == [42.0, 0.4, 0.2, 0.3]
    d = decode(msg, "/plant/y", labels=LABELS, require_stamp=True)
    assert d.stamp == 42 and d.labels == LABELS
    np.testing.assert_array_equal(d.values, [0.4, 0.2, 0.3])


def test_labels_round_trip_and_comma_refused():
    assert split_labels(join_labels(LABELS)) == LABELS
    assert split_labels("") == ()
    with pytest.raises(MessageError, match="comma"):
        join_labels(["a,b"])


def test_plain_message_is_stamped_on_arrival_per_topic():
    st = ArrivalStamper()
    a = st.stamp(decode(plain([1.0, 2.0, 3.0]), "/plant/y", labels=LABELS))
    b = st.stamp(decode(plain([1.0, 2.0, 3.0]), "/plant/y", labels=LABELS))
    assert (a.stamp, b.stamp) == (0, 1)
    assert a.labels == LABELS  # a message without labels gets the expected ones
    stamped = st.stamp(decode(plain([7.0, 1.0, 2.0, 3.0], offset=1), "/plant/y"))
    assert stamped.stamp == 7 and st.next == 2


@pytest.mark.parametrize("msg, match", [
    (plain([1.0, 2.0]), "wrong length: 2 values, expected 3"),
    (plain([5.0, 1.0, 2.0], offset=1), r"stamp 5: wrong length: 2 values, expected 3"),
    (plain([1.0, math.nan, 3.0]), "value h2 is nan"),
    (plain([3.0, 1.0, 2.0, math.inf], offset=1), "stamp 3: value h3 is inf"),
    (plain([1.5, 1.0, 2.0, 3.0], offset=1), r"stamp data\[0\] = 1.5"),
    (plain([-1.0, 1.0, 2.0, 3.0], offset=1), r"stamp data\[0\] = -1.0"),
    (plain([math.nan, 1.0, 2.0, 3.0], offset=1), r"stamp data\[0\] = nan"),
    (plain([1.0, 2.0, 3.0], offset=2), "data_offset 2"),
    (plain([], offset=1), "no stamp"),
    (plain([0.0, 1.0, 2.0, 3.0], offset=1, label="a,b,c", size=3), "channels a,b,c"),
    (plain([0.0, 1.0, 2.0, 3.0], offset=1, label="h1,h2,h3", size=4), "size 4 but 3"),
    (plain([0.0, 1.0, 2.0, 3.0], offset=1, label="h1,h2", size=3), "2 labels for 3"),
])
def test_bad_messages_raise_one_line(msg, match):
    with pytest.raises(MessageError, match=match) as info:
        decode(msg, "/plant/y", labels=LABELS)
    assert "\n" not in str(info.value) and "/plant/y" in str(info.value)


def test_missing_stamp_where_required():
    with pytest.raises(MessageError, match="/fd/residual: missing stamp"):
        decode(plain([1.0, 2.0, 3.0]), "/fd/residual", labels=LABELS, require_stamp=True)


def test_size_without_labels_and_bad_stamp_encoding():
    assert decode(plain([0.0, 1.0], offset=1), "t", size=1).values.tolist() == [1.0]
    with pytest.raises(MessageError, match="out of range"):
        encode_data(-1, [1.0])
    assert encode_data(3, np.array([1.0, 2.0])) == [3.0, 1.0, 2.0]


def test_nan_and_inf_only_where_allowed():
    """NaN = no override (fd/threshold_override), +inf = no threshold in force (a recorded
    fd/threshold of a settling bank); both refused on the data path by default."""
    for v, kw in ((math.nan, {"allow_nan": True}), (math.inf, {"allow_inf": True})):
        msg = plain([3.0, 1.0, v, 2.0], offset=1, label="h1,h2,h3", size=3)
        with pytest.raises(MessageError, match="value h2 is"):
            decode(msg, "/x")
        other = {"allow_inf": True} if "allow_nan" in kw else {"allow_nan": True}
        with pytest.raises(MessageError, match="value h2 is"):
            decode(msg, "/x", **other)
        d = decode(msg, "/x", **kw)
        assert d.stamp == 3 and d.values[0] == 1.0 and d.values[2] == 2.0
