"""Bags offline (no rclpy): simulate -> MCAP bag -> arrays, write/read round trip, errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fd_monitor.commands.simulate import simulate_to_bag
from fd_monitor.core.simulator import simulate
from fd_monitor.model.errors import BagError
from fd_monitor.model.scenario import load_scenario
from fd_monitor.wire.bag_reader import arrays_from, read_bag, read_messages
from fd_monitor.wire.bag_scanner import bag_topics
from fd_monitor.wire.bag_writer import BagWriter, write_bag


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    """The demo scenario, 30 s (300 samples), written by `simulate`."""
    path = tmp_path_factory.mktemp("bags") / "sim"
    simulate_to_bag("three_tank_bias_h1", path, seed=3, duration=30.0)
    return path


def test_simulate_bag_holds_the_simulator_arrays(sim_bag):
    sc = load_scenario("three_tank_bias_h1")
    traj = simulate(sc, 3, 300)
    b = read_bag(sim_bag)
    assert set(b) == {"/plant/u", "/plant/y", "/plant/truth"}
    np.testing.assert_array_equal(b["/plant/y"].stamps, np.arange(300))
    np.testing.assert_array_equal(b["/plant/y"].values, traj.y[0])
    np.testing.assert_array_equal(b["/plant/u"].values, traj.u[0])
    assert b["/plant/u"].labels == ("q1", "q2", "v13")
    truth = b["/plant/truth"]
    np.testing.assert_array_equal(truth.column("mode"), traj.mode[0])
    np.testing.assert_array_equal(truth.column("x.h2"), traj.x[0][:, 1])
    np.testing.assert_array_equal(truth.column("f.bias_h1"), traj.faults[0][:, 0])
    np.testing.assert_array_equal(b["/plant/y"].receive_ns, np.arange(300) * 100_000_000)
    assert bag_topics(sim_bag)["/plant/y"] == ("std_msgs/msg/Float64MultiArray", 300)


def test_write_read_round_trip_in_timestamp_order(tmp_path):
    a = arrays_from("/a", ("x", "y"), [0, 1, 2], [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]],
                    [0, 10, 20])
    b = arrays_from("/b", ("z",), [5, 6], [[7.0], [8.0]], [5, 15])
    write_bag(tmp_path / "bag", [a, b])
    got = read_bag(tmp_path / "bag")
    for want in (a, b):
        g = got[want.topic]
        assert g.labels == want.labels
        np.testing.assert_array_equal(g.stamps, want.stamps)
        np.testing.assert_array_equal(g.values, want.values)
        np.testing.assert_array_equal(g.receive_ns, want.receive_ns)
    order = [(t, int(ts)) for t, ts, _ in read_messages(tmp_path / "bag")]
    assert order == [("/a", 0), ("/b", 5), ("/a", 10), ("/b", 15), ("/a", 20)]


def test_unstamped_messages_are_numbered(tmp_path):
    from fd_monitor.wire.bag_reader import _typestore

    types = _typestore().types
    with BagWriter(tmp_path / "bag") as w:
        w.add_topic("/robot/y")
        for i in range(3):
            msg = types["std_msgs/msg/Float64MultiArray"](
                layout=types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
                data=np.array([float(i), 2.0 * i]))
            w.write_raw("/robot/y", i, bytes(_typestore().serialize_cdr(
                msg, "std_msgs/msg/Float64MultiArray")))
    got = read_bag(tmp_path / "bag")["/robot/y"]
    np.testing.assert_array_equal(got.stamps, [0, 1, 2])
    np.testing.assert_array_equal(got.values[:, 1], [0.0, 2.0, 4.0])


def test_bag_errors(tmp_path, sim_bag):
    with pytest.raises(BagError, match="no such bag"):
        read_bag(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        read_bag(tmp_path / "empty")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "metadata.yaml").write_text("hello: [")
    with pytest.raises(BagError, match="not a readable rosbag2 bag"):
        bag_topics(tmp_path / "junk")
    with pytest.raises(BagError, match=r"no topic /fd/alarm in the bag \(topics: /plant/truth"):
        read_bag(sim_bag, ["/fd/alarm"])
    with pytest.raises(BagError, match="already exists"):
        BagWriter(sim_bag)
    with pytest.raises(BagError, match=r"values of shape \(2, 1\), expected \(2, 2\)"):
        arrays_from("/a", ("x", "y"), [0, 1], [[1.0], [2.0]], [0, 1])


def test_simulate_cli_json_and_errors(tmp_path):
    out = subprocess.run([sys.executable, "-m", "fd_monitor", "simulate", "three_tank_bias_h1",
                          "-o", str(tmp_path / "b"), "--duration", "2.0", "--json"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    import json

    doc = json.loads(out.stdout)
    assert doc["samples"] == 20 and doc["seed"] == 1
    assert doc["faults"][0]["channel"] == "bias_h1"
    for args, match in [
        (["simulate", "no_such_scenario", "-o", str(tmp_path / "c")], "unknown scenario"),
        (["simulate", "three_tank_bias_h1", "-o", str(tmp_path / "b")], "already exists"),
        (["simulate", "three_tank_bias_h1", "-o", str(tmp_path / "d"), "--duration", "0.01"],
         "at least one sample"),
    ]:
        r = subprocess.run([sys.executable, "-m", "fd_monitor", *args], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 2
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and match in lines[0], r.stderr


def test_bags_module_does_not_import_rclpy():
    code = ("import sys, fd_monitor.wire.bag_writer, fd_monitor.wire.bag_scanner, "
            "fd_monitor.wire.bag_reader, fd_monitor.commands.simulate; "
            "sys.exit('rclpy' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == 0


def _f64ma_fields(msg):
    """A Float64MultiArray's fields as plain values (rosbags dataclass or the fast reader's)."""
    return ([(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim],
            int(msg.layout.data_offset), msg.data.dtype, msg.data.tobytes())


def test_float64multiarray_fast_decoder_agrees_with_rosbags_on_mangled_bytes():
    """The offline reader decodes Float64MultiArray CDR without the rosbags type store
    (conversions.parse_cdr); on valid messages and on 24,000 seeded mutations of them (bit
    flips, truncations, extra bytes, random bytes) it accepts exactly the little-endian
    bytes rosbags accepts, with the same fields, and leaves every other case to rosbags."""
    import random

    from fd_monitor.wire.bag_reader import _typestore
    from fd_monitor.wire.bag_writer import serialize_array
    from fd_monitor.wire.conversions import parse_cdr

    store = _typestore()
    ty = "std_msgs/msg/Float64MultiArray"
    types = store.types
    plain = types[ty](layout=types["std_msgs/msg/MultiArrayLayout"](
        dim=[types["std_msgs/msg/MultiArrayDimension"](label="a", size=1, stride=1),
             types["std_msgs/msg/MultiArrayDimension"](label="bcdéf", size=2, stride=2)],
        data_offset=0), data=np.arange(3.0))
    bases = [serialize_array(("h1", "h2", "h3"), 5, [1.0, -2.5, 3e-9]),
             serialize_array(("u",), 2**40, [0.5]), serialize_array((), 3, []),
             bytes(store.serialize_cdr(plain, ty))]

    def rosbags_or_none(raw):
        try:
            return store.deserialize_cdr(raw, ty)
        except Exception:      # rosbags' SerdeError and friends: the bytes do not decode
            return None

    rng = random.Random(7)
    accepted = 0
    for base in bases:
        assert _f64ma_fields(parse_cdr(base)) == _f64ma_fields(store.deserialize_cdr(base, ty))
        for _ in range(6000):
            x = bytearray(base)
            op = rng.random()
            if op < 0.5:
                for _ in range(rng.randint(1, 3)):
                    x[rng.randrange(len(x))] ^= 1 << rng.randrange(8)
            elif op < 0.7:
                del x[rng.randrange(len(x)):]
            elif op < 0.85:
                x += rng.randbytes(rng.randint(1, 12))
            else:
                x[rng.randrange(len(x))] = rng.randrange(256)
            raw = bytes(x)
            fast, ref = parse_cdr(raw), rosbags_or_none(raw)
            if ref is not None and raw[:2] == b"\x00\x01":
                accepted += 1
                assert fast is not None, raw
            if fast is not None:
                assert ref is not None and _f64ma_fields(fast) == _f64ma_fields(ref), raw
    assert accepted > 5000      # the mutations exercise the accepting path, not only errors


def test_messages_from_raw_big_endian_and_bad_bytes_go_through_rosbags():
    """Big-endian CDR (which the fast path leaves alone) reads as rosbags reads it; bytes of
    no Float64MultiArray give the one BagError naming the bag, topic and time."""
    from fd_monitor.wire.bag_reader import _typestore, messages_from_raw
    from fd_monitor.wire.bag_writer import serialize_array

    store = _typestore()
    ty = "std_msgs/msg/Float64MultiArray"
    le = serialize_array(("h1", "h2"), 4, [1.0, 2.0])
    be = bytes(store.serialize_cdr(store.deserialize_cdr(le, ty), ty, little_endian=False))
    assert be[:2] == b"\x00\x00"
    (_t, _ts, a), (_t2, _ts2, b) = messages_from_raw("bag", [("/y", ty, 1, le), ("/y", ty, 2, be)])
    assert _f64ma_fields(a)[:2] == _f64ma_fields(b)[:2]
    np.testing.assert_array_equal(a.data, [4.0, 1.0, 2.0])
    np.testing.assert_array_equal(b.data, a.data)
    with pytest.raises(BagError, match=r"bag: /y at 3\.000 s: not a valid "
                                       r"std_msgs/msg/Float64MultiArray \(SerdeError\)"):
        list(messages_from_raw("bag", [("/y", ty, 3_000_000_000, le[:-9])]))


def test_message_index_check_accepts_only_what_the_strict_parser_accepts(repo):
    """Reading skips the strict round trip of MessageIndex records (bag_scanner._message_index_ok,
    the index is never used): over the bundled bag's index records and 20,000 seeded
    mutations of them, every record the check accepts is one bag_scanner._parse accepts."""
    import random
    import struct

    from mcap.opcode import Opcode

    from fd_monitor.wire.bag_scanner import _message_index_ok, _parse, mcap_file

    buf = mcap_file(repo / "bags" / "three_tank_bias_h1").read_bytes()
    records, pos = [], 8
    while pos + 9 <= len(buf) and buf[pos] != Opcode.DATA_END:
        end = pos + 9 + struct.unpack_from("<Q", buf, pos + 1)[0]
        if buf[pos] == Opcode.MESSAGE_INDEX:
            records.append(buf[pos:end])
        pos = end
    assert len(records) > 10
    rng = random.Random(11)
    accepted = 0
    for i in range(20000):
        rec = bytearray(records[i % len(records)])
        if i >= len(records):
            for _ in range(rng.randint(1, 2)):
                rec[rng.randrange(9, len(rec))] ^= 1 << rng.randrange(8)
            if rng.random() < 0.2:
                del rec[rng.randrange(9, len(rec)):]
                rec[1:9] = struct.pack("<Q", len(rec) - 9)
        if _message_index_ok(bytes(rec), 0, len(rec)):
            accepted += 1
            assert _parse(bytes(rec), 0, len(rec)).channel_id >= 0
        else:
            with pytest.raises(Exception):  # noqa: B017  (mcap's assorted errors)
                _parse(bytes(rec), 0, len(rec))
    assert accepted > 10000


def test_arrays_of_one_layout_equal_the_message_by_message_reading(repo):
    """read_bag reads the topics whose messages share their layout bytes as one array
    (bag_reader._arrays_of_one_layout); on the bundled bag, an unstamped topic and NaN/inf values
    it gives exactly what decoding message by message gives, and it leaves any bag with a
    stamp decode() refuses (NaN, negative, 1.5, 2**53) to that loop, which names it."""
    from fd_monitor.wire.bag_reader import (
        _arrays_message_by_message,
        _arrays_of_one_layout,
        _typestore,
    )
    from fd_monitor.wire.bag_scanner import read_raw
    from fd_monitor.wire.bag_writer import serialize_array

    ty = "std_msgs/msg/Float64MultiArray"
    st = _typestore()
    bundled = list(read_raw(repo / "bags" / "three_tank_bias_h1"))
    labelled = [("/l", ty, 10 * k, serialize_array(("a", "b"), k, [k, -k])) for k in range(5)]
    special = [("/s", ty, k, serialize_array(("x",), k, [v]))
               for k, v in enumerate([np.nan, np.inf, -np.inf, 0.0])]
    plain = [("/plain", ty, k, bytes(st.serialize_cdr(st.types[ty](   # a driver's: no stamp
        layout=st.types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
        data=np.array([k, 2.0 * k])), ty))) for k in range(4)]
    for recs in (bundled, labelled + special + plain):
        fast = _arrays_of_one_layout(recs)
        slow = _arrays_message_by_message("bag", recs)
        assert fast is not None and list(fast) == list(slow)
        for topic, a in slow.items():
            b = fast[topic]
            assert (b.topic, b.labels) == (a.topic, a.labels)
            for f in ("stamps", "values", "receive_ns"):
                x, y = getattr(a, f), getattr(b, f)
                assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    assert fast["/plain"].labels == ("0", "1")
    np.testing.assert_array_equal(fast["/plain"].stamps, np.arange(4))
    for bad in (np.nan, -1.0, 1.5, 2.0**53):
        data = serialize_array(("x",), 0, [1.0])
        raw = data[:-16] + np.array([bad, 1.0]).tobytes()
        recs = [*special[:2], ("/s", ty, 9, raw)]
        assert _arrays_of_one_layout(recs) is None
        with pytest.raises(BagError, match=r"bag: /s: stamp data\[0\] = "):
            _arrays_message_by_message("bag", recs)
