"""Message adapters (fd_monitor/wire/adapters.py): a robot's JointState, Odometry, Twist,
Float64 and Float64MultiArray topics as the monitor's u and y. Pure: no rclpy (rosbags'
message classes, which the same decoding reads), bags written into tmp_path."""

from __future__ import annotations

import numpy as np
import pytest

from fd_monitor.model.errors import BagError
from fd_monitor.wire.adapters import (
    AdaptedMessageError,
    AdapterError,
    AdapterJoin,
    decode_message,
    encode,
    load_adapter,
    parse_adapter,
    read_adapted,
    rosbags_make,
)

JS = "sensor_msgs/msg/JointState"
MAP = {
    "inputs": [
        {"channel": "effort", "topic": "/cmd", "type": "std_msgs/Float64MultiArray", "index": 1},
        {"channel": "v_cmd", "topic": "/cmd_vel", "type": "geometry_msgs/Twist",
         "field": "linear.x"},
        {"channel": "gain", "topic": "/gain", "type": "std_msgs/Float64"},
    ],
    "outputs": [
        {"channel": "vel", "topic": "/joint_states", "type": "sensor_msgs/JointState",
         "joint": "elbow", "field": "velocity"},
        {"channel": "pos", "topic": "/joint_states", "type": JS, "joint": "elbow",
         "field": "position"},
        {"channel": "yaw", "topic": "/odom", "type": "nav_msgs/Odometry", "field": "yaw"},
        {"channel": "vx", "topic": "/odom", "type": "nav_msgs/msg/Odometry",
         "field": "linear.x"},
        {"channel": "w", "topic": "/twist", "type": "geometry_msgs/TwistStamped",
         "field": "angular.z"},
        {"channel": "lab", "topic": "/arr", "type": "std_msgs/Float64MultiArray",
         "label": "b"},
    ],
}


def _roundtrip(msg, ty):
    from fd_monitor.wire.bag_reader import _typestore

    store = _typestore()
    return store.deserialize_cdr(bytes(store.serialize_cdr(msg, ty)), ty)


def test_every_type_encodes_and_decodes_by_attribute():
    ad = parse_adapter(MAP, "map.yaml")
    assert ad.clock_topic == "/joint_states"
    u = [0.25, -1.5, 3.0]
    y = [1.25, -0.5, 0.75, 2.0, -0.125, 9.5]
    got = {}
    for topic, ty, msg in encode(ad, 1_234_567_890, u, y, rosbags_make):
        r = decode_message(ad, topic, _roundtrip(msg, ty), receive_ns=7)
        got.update(r.values)
        # header types are timed by their stamp, the others by the receive time
        assert r.stamp_ns == (1_234_567_890 if ad.header_topic(topic) else 7), topic
    want = dict(zip(["effort", "v_cmd", "gain", "vel", "pos", "yaw", "vx", "w", "lab"], u + y))
    assert got == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("edit, match", [
    (lambda m: m["outputs"][0].update(type="sensor_msgs/Imu"),
     r"outputs\[0\]\.type: 'sensor_msgs/Imu': expected one of"),
    (lambda m: m["outputs"][0].pop("joint"), r"outputs\[0\]\.joint: expected the joint's name"),
    (lambda m: m["outputs"][0].update(field="speed"),
     r"outputs\[0\]\.field: 'speed' is not a field of sensor_msgs/msg/JointState"),
    (lambda m: m["outputs"][2].update(field="pose.x"),
     r"outputs\[2\]\.field: 'pose.x' is not a field of nav_msgs/msg/Odometry"),
    (lambda m: m["inputs"][0].update(label="a"), r"inputs\[0\]: expected exactly one of label"),
    (lambda m: m["inputs"][0].update(index=-1), r"inputs\[0\]\.index: expected an integer >= 0"),
    (lambda m: m["inputs"][1].update(topic="/joint_states"),
     r"topic /joint_states: mapped as sensor_msgs/msg/JointState and as geometry_msgs"),
    (lambda m: m["outputs"][1].update(channel="vel"), r"outputs: channel 'vel' mapped twice"),
    (lambda m: m["outputs"].clear(), r"outputs: expected a list .*sample clock"),
    (lambda m: m.update(rate=3), r"rate: unknown key"),
    (lambda m: m["inputs"][2].update(scale=2.0), r"inputs\[2\]\.scale: unknown key"),
])
def test_bad_mapping_is_one_line_naming_the_key(edit, match):
    import copy

    doc = copy.deepcopy(MAP)
    edit(doc)
    with pytest.raises(AdapterError, match=match) as exc:
        parse_adapter(doc, "map.yaml")
    assert "\n" not in str(exc.value) and str(exc.value).startswith("map.yaml")


def test_mapping_must_be_the_plants_channels():
    from fd_monitor.model.system import load_system

    ad = load_adapter("dc_motor")
    system = load_system("dc_motor")
    assert ad.for_system(system).outputs[0].name == "velocity"
    with pytest.raises(AdapterError, match=r"inputs: no mapping for q1, q2, v13; effort "
                                           r"not a plant input"):
        ad.for_system(load_system("three_tank"))


def _joint_state(names, velocity, stamp_ns=5):
    return rosbags_make(JS, header=rosbags_make(
        "std_msgs/msg/Header", stamp=rosbags_make("builtin_interfaces/msg/Time",
                                                  sec=0, nanosec=stamp_ns), frame_id=""),
        name=names, position=np.zeros(0), velocity=np.asarray(velocity, float),
        effort=np.zeros(0))


@pytest.mark.parametrize("msg, topic, match, kind", [
    (_joint_state(["shoulder"], [1.0]), "/joint_states",
     r"/joint_states stamp .*\(vel\): no joint 'elbow' \(joints: shoulder\)", "malformed"),
    (_joint_state(["elbow", "wrist"], [1.0]), "/joint_states",
     r"no velocity for joint 'elbow'|no position for joint", "malformed"),
    (_joint_state(["elbow"], [float("nan")]), "/joint_states", r"value is nan", "non_finite"),
    (rosbags_make("std_msgs/msg/Float64", data=1.0), "/cmd", r"/cmd at .*: not a "
     r"std_msgs/msg/Float64MultiArray with the mapped fields", "malformed"),
])
def test_bad_message_is_one_line_with_its_kind(msg, topic, match, kind):
    ad = parse_adapter(MAP, "map.yaml")
    with pytest.raises(AdaptedMessageError, match=match) as exc:
        decode_message(ad, topic, msg, 0)
    assert exc.value.kind == kind and "\n" not in str(exc.value)


def _motor_adapter():
    return parse_adapter({
        "inputs": [{"channel": "effort", "topic": "/cmd", "type": "std_msgs/Float64MultiArray",
                    "index": 0}],
        "outputs": [{"channel": "velocity", "topic": "/js", "type": JS, "joint": "m",
                     "field": "velocity"}]}, "motor.yaml")


def _put(join, ad, t_ns, u=None, y=None, now=None, recv=None):
    for topic, _ty, msg in encode(ad, t_ns, [0.0 if u is None else u],
                                  [0.0 if y is None else y], rosbags_make):
        if (topic == "/cmd" and u is not None) or (topic == "/js" and y is not None):
            join.put(topic, msg, t_ns if recv is None else recv, now)


def test_join_samples_every_channel_onto_the_grid():
    """The time base (wire/timebase.py) on a hand-made stream: the grid's phase from the
    clock's stamps, a command 2 ms after its measurement is that sample's, a lost measurement
    is a gap, a sample with no command yet is ``no_value``, the same stamp twice a duplicate."""
    ad = _motor_adapter()
    j = AdapterJoin(ad, 0.01)
    ms = 1_000_000
    for k in range(20):
        if k == 7:
            continue                                  # measurement 7 lost
        t = 10**15 + k * 10 * ms + (ms if k % 2 else -ms)    # +-1 ms jitter
        _put(j, ad, t, y=float(k), recv=t)
        if k == 3:
            _put(j, ad, t, y=99.0, recv=t + ms)       # the same stamp again
        if k >= 2:
            _put(j, ad, 10**15 + k * 10 * ms + 2 * ms, u=10.0 + k)   # 2 ms after y_k
    out = j.ready()
    got = {s.k: (float(s.u[0]), float(s.y[0])) for s in out}
    assert sorted(got) == [k for k in range(20) if k not in (0, 1, 7)]
    assert all(got[k] == (10.0 + k, float(k)) for k in got)
    c = j.counts()
    assert c["gaps"] == {"no_value": {"effort": 2}, "stale": {"velocity": 1}}
    assert c["duplicate"] == {"/js": 1}
    assert [k for k, _ in j.take_errors()] == ["duplicate"]


def test_live_join_decides_on_data_or_after_a_silence():
    ad = _motor_adapter()
    j = AdapterJoin(ad, 0.01, hold_wait=0.1)
    ms = 1_000_000
    for k in range(16):                               # the warm-up: the grid's phase
        _put(j, ad, k * 10 * ms, y=float(k), now=k * 0.01)
        _put(j, ad, k * 10 * ms, u=0.5, now=k * 0.01 + 0.001, recv=k * 10 * ms + ms)
    assert [s.k for s in j.ready(now=0.151)] == list(range(15))   # 15: its command is in,
    _put(j, ad, 160 * ms, y=16.0, now=0.16)          # but sample 15 may get more: decided
    assert [s.k for s in j.ready(now=0.161)] == [15]  # when topic data for 16 arrive
    assert j.ready(now=0.2) == []                     # 16: its command may be on the way
    (s,) = j.ready(now=0.261)                         # a silence of hold_wait: held
    assert (s.k, float(s.u[0]), s.held) == (16, 0.5, ("effort",))


def test_bag_through_the_adapter_equals_the_simulation(tmp_path):
    from fd_monitor.commands.simulate import simulate_to_bag
    from fd_monitor.core.simulator import simulate
    from fd_monitor.model.scenario import load_scenario
    from fd_monitor.model.system import load_system
    from fd_monitor.wire.bag_scanner import bag_topics

    bag = tmp_path / "motor"
    info = simulate_to_bag("dc_motor_bias_velocity", bag, seed=3, duration=3.0,
                           adapter="dc_motor")
    assert info["topics"] == ["/effort_controller/commands", "/joint_states", "/plant/truth"]
    topics = bag_topics(bag)
    assert topics["/joint_states"] == (JS, 300) and "/plant/y" not in topics
    tr = simulate(load_scenario("dc_motor_bias_velocity"), 3, 300)
    s = read_adapted(bag, "dc_motor", system=load_system("dc_motor"))
    assert s.errors == [] and s.sample_time == 0.01
    np.testing.assert_array_equal(s.k, np.arange(300))
    np.testing.assert_array_equal(s.u, tr.u[0])
    np.testing.assert_array_equal(s.y, tr.y[0])
    # without a plant: the sample time from the stamps, the channels from the file
    s2 = read_adapted(bag, "dc_motor")
    assert s2.sample_time == pytest.approx(0.01) and s2.outputs == ("velocity",)


def test_bag_without_the_mapped_topic_or_of_another_type(tmp_path):
    from fd_monitor.commands.simulate import simulate_to_bag

    plain = tmp_path / "plain"
    simulate_to_bag("dc_motor_nominal", plain, duration=0.5)
    with pytest.raises(BagError, match=r"no topic .*/joint_states.* in the bag"):
        read_adapted(plain, "dc_motor")
    ad = parse_adapter({"outputs": [{"channel": "velocity", "topic": "/plant/y",
                                     "type": JS, "joint": "m", "field": "velocity"}]}, "m.yaml")
    with pytest.raises(BagError, match=r"/plant/y is recorded as "
                                       r"std_msgs/msg/Float64MultiArray, the adapter m.yaml "
                                       r"maps it as sensor_msgs/msg/JointState"):
        read_adapted(plain, ad)
