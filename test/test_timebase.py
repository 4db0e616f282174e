"""The one time base (fd_monitor/wire/timebase.py through wire/adapters.py): robot bags that
fd_monitor did not write -- jittered stamps, a controller answering a few ms late, faster and
slower topics, lost messages, stamps from 0, a clock that jumps, 10 minutes at 100 Hz -- are
sampled onto the plant's grid with nothing lost silently: every sample is analysed or counted
as a gap, the values are the simulation's own, and `analyze` accounts for every sample
(used = present - gaps). Pure (rosbags writes the bags); no rclpy."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ros_util import run_cli

from fd_monitor.analysis.offline import run_bag
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.adapters import (
    AdapterJoin,
    encode,
    load_adapter,
    parse_adapter,
    read_adapted,
    rosbags_make,
)
from fd_monitor.wire.bag_reader import _typestore
from fd_monitor.wire.bag_writer import BagWriter
from fd_monitor.wire.timebase import snap_sample_time

PLANT, GAINS = "dc_motor_identified", "dc_motor_identified_thresholds"
JS, CMD = "/joint_states", "/effort_controller/commands"
TS = 0.01
MS = 1_000_000


def robot_bag(path, n, *, scenario="dc_motor_nominal", seed=1, jitter=0.0, late=(1.0, 3.0),
              u_every=1, u_faster=False, y_lost=0.0, u_lost=0.0, t0_ns=1_700_000_000 * 10**9,
              restart_at=None, tile=1):
    """A ros2_control-like bag of the simulated motor: /joint_states (JointState, header
    stamp t_k + jitter * Ts * U(-1, 1), recorded 0.2 ms after t_k) and the effort controller's
    Float64MultiArray answering each measurement ``late`` ms (uniform) after it (no header:
    its receive time is its time). ``u_every``: a command every that many samples (a slower
    topic); ``u_faster``: a second command at t_k + Ts/2 (a faster one); ``*_lost``: the
    fraction of messages lost; ``restart_at``: the stamps start again from t0 at that sample
    (a restarted driver); ``tile``: the simulation of n / tile samples repeated (a long bag
    at a fraction of the simulator's time). Returns (u, y, lost y samples, lost u samples)."""
    rng = np.random.default_rng(seed)
    tr = simulate(load_scenario(scenario), seed, n // tile)
    u, y = np.tile(tr.u[0], (tile, 1)), np.tile(tr.y[0], (tile, 1))
    js, cmd = _templates()
    lost_y = set(np.flatnonzero(rng.random(n) < y_lost).tolist()) if y_lost else set()
    lost_u = set(np.flatnonzero(rng.random(n) < u_lost).tolist()) if u_lost else set()
    recs = []
    for k in range(n):
        kk = k if restart_at is None or k < restart_at else k - restart_at
        tk = t0_ns + round(kk * TS * 1e9)
        log0 = t0_ns + round(k * TS * 1e9) + (10**9 if restart_at and k >= restart_at else 0)
        stamp = tk + round(jitter * TS * 1e9 * rng.uniform(-1, 1))
        got_y = log0 + 200_000                    # published on time, stamped with jitter
        if k not in lost_y:
            recs.append((got_y, JS, js(stamp, y[k, 0])))
        # the command for sample k answers y_k: 1-3 ms after it (its receive time)
        if k % u_every == 0 and k not in lost_u:
            d = round(rng.uniform(*late) * MS)
            data = cmd(u[k, 0])
            recs.append((got_y + d, CMD, data))
            if u_faster:
                recs.append((log0 + d + round(TS * 1e9 / 2), CMD, data))
    recs.sort(key=lambda r: r[0])
    with BagWriter(path) as w:
        w.add_topic(CMD, "std_msgs/msg/Float64MultiArray")
        w.add_topic(JS, "sensor_msgs/msg/JointState")
        for t, topic, data in recs:
            w.write_raw(topic, t, bytes(data))
    return u, y, lost_y, lost_u


def _templates():
    """Fast CDR of the two messages (rosbags' serializer for 60,000 messages takes 20 s):
    one message of each serialised by rosbags with marker values, then the stamp and value
    written at the markers' offsets."""
    import struct

    ad = load_adapter("dc_motor").for_system(load_system("dc_motor"))
    store = _typestore()
    sec, ns, val = 0x5EADBEEF, 0x3ADBEEF, 1.2345678e300
    msgs = {t: m for t, _ty, m in encode(ad, sec * 10**9 + ns, [val], [val], rosbags_make)}
    raw_js = bytes(store.serialize_cdr(msgs[JS], "sensor_msgs/msg/JointState"))
    raw_cmd = bytes(store.serialize_cdr(msgs[CMD], "std_msgs/msg/Float64MultiArray"))
    i_sec, i_ns = raw_js.index(struct.pack("<i", sec)), raw_js.index(struct.pack("<I", ns))
    i_v, i_u = raw_js.index(struct.pack("<d", val)), raw_cmd.index(struct.pack("<d", val))

    def js(stamp, v):
        b = bytearray(raw_js)
        struct.pack_into("<i", b, i_sec, stamp // 10**9)
        struct.pack_into("<I", b, i_ns, stamp % 10**9)
        struct.pack_into("<d", b, i_v, v)
        return bytes(b)

    def cmd(v):
        b = bytearray(raw_cmd)
        struct.pack_into("<d", b, i_u, v)
        return bytes(b)

    # the templates read back as rosbags' own messages
    back = store.deserialize_cdr(js(7 * 10**9 + 5, 0.25), "sensor_msgs/msg/JointState")
    assert (back.header.stamp.sec, back.header.stamp.nanosec, list(back.velocity)) == \
        (7, 5, [0.25])
    return js, cmd


def _read(bag, **kw):
    return read_adapted(bag, "dc_motor", system=load_system(PLANT), **kw)


def test_jitter_of_0_4_ts_and_a_late_controller_give_every_sample_exactly(tmp_path):
    u, y, _, _ = robot_bag(tmp_path / "b", 2000, jitter=0.4, late=(1.0, 3.0))
    s = _read(tmp_path / "b")
    np.testing.assert_array_equal(s.k, np.arange(2000))
    np.testing.assert_array_equal(s.y, y)         # every measurement in its own sample
    np.testing.assert_array_equal(s.u, u)         # the command answering it, not the previous
    assert s.gaps == [] and s.counts["held"] == {} and s.errors == []


def test_lost_messages_are_gaps_for_outputs_and_held_for_inputs(tmp_path):
    u, y, lost_y, lost_u = robot_bag(tmp_path / "b", 4000, jitter=0.2, y_lost=1 / 200,
                                     u_lost=1 / 200, seed=4)
    assert lost_y and lost_u
    s = _read(tmp_path / "b")
    # a lost measurement is a gap (outputs are not held by default), nothing else is
    lost_y_inside = {k for k in lost_y if 0 < k < 3999}
    assert {k for k, reason, ch in s.gaps} == lost_y_inside
    assert all(reason == "stale" and ch == "velocity" for _, reason, ch in s.gaps)
    assert set(s.k.tolist()) == set(range(4000)) - lost_y_inside - ({0} & lost_y)
    # a lost command is held (an actuator holds it): the previous one, counted
    i = {k: j for j, k in enumerate(s.k.tolist())}
    for k in sorted(lost_u - lost_y):
        if 0 < k and k in i:
            assert s.u[i[k], 0] == u[k - 1, 0]
    assert s.counts["held"]["effort"] == len([k for k in lost_u - lost_y if 0 < k < 4000])
    ok = [j for j, k in enumerate(s.k.tolist()) if k not in lost_u]
    np.testing.assert_array_equal(s.u[ok], u[s.k[ok]])
    np.testing.assert_array_equal(s.y, y[s.k])


def test_a_five_times_slower_and_a_two_times_faster_command_topic(tmp_path):
    u, _y, _, _ = robot_bag(tmp_path / "slow", 1500, jitter=0.3, u_every=5)
    s = _read(tmp_path / "slow")
    np.testing.assert_array_equal(s.k, np.arange(1500))      # held 4 of 5, max_hold 0.5 s
    np.testing.assert_array_equal(s.u[:, 0], u[(np.arange(1500) // 5) * 5, 0])
    assert s.counts["held"]["effort"] == 1200
    u, _y, _, _ = robot_bag(tmp_path / "fast", 1500, jitter=0.3, u_faster=True)
    f = _read(tmp_path / "fast")
    np.testing.assert_array_equal(f.k, np.arange(1500))
    np.testing.assert_array_equal(f.u, u)
    assert f.counts["decimated"][CMD] > 0


def test_a_slower_sensor_is_held_only_when_the_adapter_says_so(tmp_path):
    """JointState at 20 Hz into a 100 Hz plant: without max_hold 4 samples of 5 are gaps
    (counted, never amnesia); with max_hold 0.05 s on the output every sample is used."""
    rng = np.random.default_rng(2)
    ad = load_adapter("dc_motor").for_system(load_system("dc_motor"))
    store = _typestore()
    n = 1000
    with BagWriter(tmp_path / "b") as w:
        w.add_topic(CMD, "std_msgs/msg/Float64MultiArray")
        w.add_topic(JS, "sensor_msgs/msg/JointState")
        for k in range(n):
            t = 10**18 + k * 10 * MS
            msgs = {tp: m for tp, _ty, m in encode(ad, t, [0.1 * k], [0.01 * k],
                                                   rosbags_make)}
            if k % 5 == 0:                          # stamps jittered by +-2 ms
                msgs = {tp: m for tp, _ty, m in encode(
                    ad, t + round(rng.uniform(-2, 2) * MS), [0.1 * k], [0.01 * k],
                    rosbags_make)}
                w.write_raw(JS, t + MS // 5,
                            bytes(store.serialize_cdr(msgs[JS], "sensor_msgs/msg/JointState")))
            w.write_raw(CMD, t + 2 * MS, bytes(store.serialize_cdr(
                msgs[CMD], "std_msgs/msg/Float64MultiArray")))
    s = _read(tmp_path / "b")
    assert len(s.k) == n // 5 and len(s.gaps) == n - n // 5
    doc = {"format_version": 1, "inputs": [{"channel": "effort", "topic": CMD,
                                            "type": "std_msgs/Float64MultiArray", "index": 0}],
           "outputs": [{"channel": "velocity", "topic": JS, "type": "sensor_msgs/JointState",
                        "joint": "motor", "field": "velocity", "max_hold": 0.05}]}
    held = read_adapted(tmp_path / "b", parse_adapter(doc, "slow.yaml"),
                        system=load_system(PLANT))
    np.testing.assert_array_equal(held.k, np.arange(n))
    np.testing.assert_array_equal(held.y[:, 0], 0.01 * ((np.arange(n) // 5) * 5))
    np.testing.assert_allclose(held.u[:, 0], 0.1 * np.arange(n))
    assert held.counts["held"]["velocity"] == n - n // 5


def test_stamps_from_zero_and_a_restarted_driver(tmp_path):
    _u, y, _, _ = robot_bag(tmp_path / "zero", 500, t0_ns=0, jitter=0.1)
    s = _read(tmp_path / "zero")
    np.testing.assert_array_equal(s.k, np.arange(500))       # stamp 0 is a stamp
    np.testing.assert_array_equal(s.y, y)
    _u, y, _, _ = robot_bag(tmp_path / "again", 600, restart_at=300, jitter=0.1)
    r = _read(tmp_path / "again")
    assert r.new_runs == [300]
    np.testing.assert_array_equal(r.k, np.arange(600))        # numbered on, both runs whole
    np.testing.assert_array_equal(r.y, y)
    run = run_bag(tmp_path / "again", GAINS, system=load_system(PLANT), adapter="dc_motor")
    assert run.inputs.restarts == [300]


def test_analyze_accounts_for_every_sample_of_a_ten_minute_lossy_bag(tmp_path):
    n = 60_000                                     # 10 minutes at 100 Hz
    _u, _y, lost_y, _ = robot_bag(tmp_path / "long", n, jitter=0.4, y_lost=1 / 200,
                                  u_lost=1 / 200, seed=9, tile=10)
    r = run_cli(["analyze", str(tmp_path / "long"), "--gains", GAINS, "--system", PLANT,
                 "--adapter", "dc_motor", "--json"], timeout=300)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    c = doc["sample_counts"]
    gaps = len({k for k in lost_y if 0 < k < n - 1})
    assert c["present"] == n - (0 in lost_y) - ((n - 1) in lost_y)
    assert c["used"] == c["present"] - gaps == doc["samples"]
    assert c["skipped"] == {"stale": gaps}
    assert doc["time_base"]["held"]["effort"] > 0 and doc["time_base"]["sample_time"] == TS


def test_the_same_messages_give_the_same_samples_in_any_interleaving(tmp_path):
    """Live, the node sees each topic in order but the topics interleaved by DDS, not as
    recorded: the time base decides on data, so a different interleaving (within the wait)
    gives the same samples."""
    robot_bag(tmp_path / "b", 800, jitter=0.4, y_lost=1 / 200, u_lost=1 / 200, seed=5)
    from fd_monitor.wire.bag_reader import messages_from_raw
    from fd_monitor.wire.bag_scanner import read_raw

    msgs = list(messages_from_raw(tmp_path / "b", list(read_raw(tmp_path / "b"))))
    ad = load_adapter("dc_motor").for_system(load_system(PLANT))

    def run(order):
        j = AdapterJoin(ad, TS)
        out = []
        for topic, t, m in order:
            j.put(topic, m, t, t * 1e-9)
            out += j.events()
        j.advance(None)
        out += j.events(True)
        return [(e.k, tuple(e.u), tuple(e.y)) if hasattr(e, "u") else (e.k, e.reason)
                for e in out]

    base = run(msgs)
    # every command moved after the next measurement (a slower path for the controller)
    swapped = list(msgs)
    for i in range(len(swapped) - 1):
        if swapped[i][0] == CMD and swapped[i + 1][0] == JS:
            swapped[i], swapped[i + 1] = swapped[i + 1], swapped[i]
    assert run(swapped) == base


@pytest.mark.parametrize("step,want", [(0.00999885, 0.01), (0.0200004, 0.02),
                                        (1 / 30 * 1.004, 1 / 30), (0.00125, 0.00125),
                                        (0.0123, 0.0123)])
def test_sample_time_snaps_to_a_round_value_within_one_percent(step, want):
    ts, snapped = snap_sample_time(step)
    assert ts == pytest.approx(want, rel=1e-12)
    assert snapped == (step != 0.0123)


def test_bad_timing_keys_in_an_adapter_file_are_one_line():
    from fd_monitor.wire.adapters import AdapterError

    base = {"outputs": [{"channel": "v", "topic": JS, "type": "sensor_msgs/JointState",
                         "joint": "m", "field": "velocity"}]}
    for doc, text in (({**base, "max_hold": 1}, r"max_hold: expected a mapping"),
                      ({**base, "wait": -1}, r"wait: expected a duration in s"),
                      ({"outputs": [{**base["outputs"][0], "max_hold": "x"}]},
                       r"outputs\[0\]\.max_hold: expected a duration"),
                      ({"outputs": [{**base["outputs"][0], "decimate": "median"}]},
                       r"outputs\[0\]\.decimate: expected last or mean")):
        with pytest.raises(AdapterError, match=text):
            parse_adapter(doc, "a.yaml")


def test_no_history_cap_a_150_s_bag_is_read_whole(tmp_path):
    """The former adapter join kept the last 10,000 messages of a held topic: a 150 s bag
    analysed as 10,000 samples, the bias injected at 30 s "detected" at 0.29 s."""
    from fd_monitor.commands.simulate import simulate_to_bag

    simulate_to_bag("dc_motor_bias_velocity", tmp_path / "m", duration=150.0,
                    adapter="dc_motor")
    run = run_bag(tmp_path / "m", GAINS, system=load_system(PLANT), adapter="dc_motor")
    assert run.inputs.sample_counts() == {"present": 15000, "used": 15000, "skipped": {}}
    np.testing.assert_array_equal(run.k, np.arange(15000))
    first = int(run.k[run.alarm.any(axis=1)][0])
    assert 3000 <= first <= 3010, first            # the bias starts at 30 s (sample 3000)
