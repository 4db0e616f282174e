"""Every command speaks adapters (issue 19, item 4): `analyze`, `report`, `evaluate`, `validate`
on a robot's own bag and adapter file, and a plant found from its gain file. Bags are written
into tmp_path (the simulated dc_motor as ros2_control publishes it,
doc/tutorial/own-robot.md); the commands run in-process through the CLI's `main`."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import yaml

from fd_monitor.analysis.offline import InputReport
from fd_monitor.commands.cli import main
from fd_monitor.core.methods import load_gains
from fd_monitor.model.paths import path_for_file, resolve_for_file

CONFIG = Path(__file__).resolve().parent.parent / "config"   # the shipped files

GAINS = "dc_motor_identified_thresholds"
#: Every shipped adapter file -> (a faulty scenario of its plant, the gain file that monitors
#: it, the fault's first sample): the commands are shown on each.
SHIPPED = {"dc_motor": ("dc_motor_bias_velocity", GAINS, 3000)}
JOINT_STATES, COMMANDS = "/joint_states", "/effort_controller/commands"


def _cli(capsys, *args):
    """(status, stdout, stderr) of ``python -m fd_monitor ARGS`` run in this process."""
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _robot_bag(tmp_path, name="motor", scenario="dc_motor_bias_velocity", seconds=3.0,
               drop=()):
    """A simulated dc_motor bag on the robot's topics, with the ``(topic, i)``-th messages of
    ``drop`` left out (a lost message)."""
    from fd_monitor.commands.simulate import simulate_to_bag
    from fd_monitor.wire.bag_scanner import read_raw
    from fd_monitor.wire.bag_writer import BagWriter

    full = tmp_path / f"{name}_full"
    simulate_to_bag(scenario, full, seed=3, duration=seconds, adapter="dc_motor")
    if not drop:
        return full
    out = tmp_path / name
    w = BagWriter(out)
    seen: dict[str, int] = {}
    for topic, ty, t, data in read_raw(full):
        i = seen.get(topic, 0)
        seen[topic] = i + 1
        if (topic, i) in drop:
            continue
        w.add_topic(topic, ty)
        w.write_raw(topic, t, bytes(data))
    w.close()
    return out


# -- analyze: a skip without a stamp beside a hole -------------------------------------------


def test_by_kind_orders_stamps_and_runs_of_one_kind():
    rep = InputReport([
        {"kind": "missing", "topic": "/y", "sample": (40, 42), "message": ""},
        {"kind": "missing", "topic": "/y", "sample": None, "message": ""},
        {"kind": "missing", "topic": "/y", "sample": 7, "message": ""},
        {"kind": "missing", "topic": "/y", "sample": [3, 5], "message": ""},
        {"kind": "duplicate", "topic": "/y", "sample": 9, "message": ""},
        {"kind": "duplicate", "topic": "/y", "sample": 2, "message": ""}])
    # the format stays: stamps as ints (-1: none), runs as [first, last], by first stamp
    assert rep.by_kind() == {"missing": [-1, [3, 5], 7, [40, 42]], "duplicate": [2, 9]}


def test_analyze_a_robot_bag_with_a_skipped_sample_and_a_hole(tmp_path, capsys):
    # no command before the first JointState and JointState 100 lost: `analyze --adapter`
    # crashed on sorting a sample without a stamp beside a run of missing samples (TypeError)
    bag = _robot_bag(tmp_path, drop={(COMMANDS, 0), (JOINT_STATES, 100)})
    code, out, err = _cli(capsys, "analyze", bag, "--gains", GAINS, "--adapter", "dc_motor",
                          "--json")
    assert code == 0, err
    doc = json.loads(out)
    kinds = {(e["kind"], tuple(e["sample"])) for e in doc["input_errors"]}
    assert kinds == {("no_value", (0, 0)), ("stale", (100, 100))}, kinds
    code, out, err = _cli(capsys, "analyze", bag, "--gains", GAINS, "--adapter", "dc_motor")
    assert code == 0, err
    assert "samples: 300 present, 298 used" in out, out


# -- report: a robot's bag -----------------------------------------------------------------


def test_every_shipped_adapter_is_covered():
    assert sorted(p.stem for p in (CONFIG / "adapters").glob("*.yaml")) == sorted(SHIPPED)


@pytest.mark.parametrize("adapter", sorted(SHIPPED))
def test_report_reads_a_robot_bag_through_its_adapter(tmp_path, capsys, adapter):
    scenario, gains, onset = SHIPPED[adapter]
    bag = tmp_path / "robot"
    assert _cli(capsys, "simulate", scenario, "--adapter", adapter, "--duration", 32, "-o",
                bag)[0] == 0
    # without --adapter: /plant/y is missing, and the error says so
    code, _out, err = _cli(capsys, "report", bag, "--gains", gains, "-o", tmp_path / "r0")
    assert code == 2 and "/plant/y" in err, err
    code, out, err = _cli(capsys, "report", bag, "--gains", gains, "--adapter", adapter,
                          "-o", tmp_path / "r", "--json")
    assert code == 0, err
    doc = json.loads(out)
    first = min(a["first_sample"] for a in doc["alarms"])
    assert onset <= first <= onset + 100, doc["alarms"]      # within 1 s of the fault
    md = (tmp_path / "r" / "summary.md").read_text()
    assert f"through adapter `{adapter}`" in md
    for fig in doc["figures"].values():
        assert Path(fig).stat().st_size > 10_000, fig
    # the same with the plant named (--system), as analyze takes it
    plant = load_gains(gains, verify=False).system_name
    code, out, err = _cli(capsys, "report", bag, "--gains", gains, "--adapter", adapter,
                          "--system", plant, "-o", tmp_path / "r2", "--json")
    assert code == 0, err
    assert json.loads(out)["alarms"] == doc["alarms"]


# -- the plant of a gain file: recorded by path when it is not a shipped one -----------------


def test_path_for_file_is_relative_to_the_anchor_and_posix(tmp_path):
    anchor = tmp_path / "gains" / "g.yaml"
    plant = tmp_path / "plants" / "sub" / "motor.yaml"
    stored = path_for_file(plant, anchor)
    assert stored == "../plants/sub/motor.yaml"
    assert resolve_for_file(stored, anchor) == plant
    assert resolve_for_file(str(plant), tmp_path / "x.yaml") == plant   # absolute: as is


def _own_plant(tmp_path):
    """The identified motor as a plant file of the user's (another name, not shipped)."""
    src = (CONFIG / "systems" / "dc_motor_identified.yaml").read_text()
    plant = tmp_path / "plants" / "motor.yaml"
    plant.parent.mkdir(parents=True)
    plant.write_text(src.replace("\nname: dc_motor_identified\n", "\nname: my_motor\n"))
    return plant


def test_analyze_finds_a_designed_plant_from_the_gain_file(tmp_path, capsys):
    plant = _own_plant(tmp_path)
    gains = tmp_path / "gains" / "motor_thresholds.yaml"
    code, _out, err = _cli(capsys, "design", "thresholds", plant, "--envelope", "declared",
                           "-o", gains)
    assert code == 0, err
    doc = yaml.safe_load(gains.read_text())
    assert doc["system"]["file"] == "../plants/motor.yaml"     # relative, POSIX
    bag = _robot_bag(tmp_path, seconds=1.0)
    code, out, err = _cli(capsys, "analyze", bag, "--gains", gains, "--adapter", "dc_motor",
                          "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["plant"] == "my_motor" and res["samples"] == 100
    # the gain file and its plant moved together: still found
    moved = tmp_path / "elsewhere"
    shutil.copytree(tmp_path / "plants", moved / "plants")
    shutil.copytree(tmp_path / "gains", moved / "gains")
    shutil.rmtree(tmp_path / "plants")
    code, out, err = _cli(capsys, "analyze", bag, "--gains", moved / "gains" / gains.name,
                          "--adapter", "dc_motor", "--json")
    assert code == 0, err
    # the gain file without its plant: the error says how to give it
    code, _out, err = _cli(capsys, "analyze", bag, "--gains", gains, "--adapter", "dc_motor")
    assert code == 2
    assert err.count("\n") == 1 and "system.file" in err and "--system" in err, err
    code, _out, err = _cli(capsys, "analyze", bag, "--gains", gains, "--adapter", "dc_motor",
                           "--system", moved / "plants" / "motor.yaml")
    assert code == 0, err


def test_a_plant_found_by_name_is_not_recorded_and_old_gain_files_verify(tmp_path, capsys):
    from fd_monitor.model.system import gain_system

    gains = tmp_path / "g.yaml"
    code, _out, err = _cli(capsys, "design", "thresholds", "dc_motor_identified",
                           "--envelope", "declared", "-o", gains)
    assert code == 0, err
    assert "file" not in yaml.safe_load(gains.read_text())["system"]
    # a shipped gain file (no system.file) still verifies and finds its plant by name
    gf = load_gains(GAINS, verify=False)
    assert gf.system_file == "" and gain_system(gf).name == "dc_motor_identified"
    load_gains(GAINS, gain_system(gf))


def test_unknown_plant_without_a_recorded_file_names_system(tmp_path, capsys):
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.gains import write_gain_doc

    # a gain file written before plant files were recorded, for a plant that is not shipped
    plant = _own_plant(tmp_path)
    gains = tmp_path / "g.yaml"
    assert _cli(capsys, "design", "thresholds", plant, "--envelope", "declared", "-o",
                gains)[0] == 0
    doc = yaml.safe_load(gains.read_text())
    del doc["system"]["file"]
    write_gain_doc(gains, doc)
    assert load_gains(gains, verify=True).system_file == ""
    bag = _robot_bag(tmp_path, seconds=0.5)
    code, _out, err = _cli(capsys, "analyze", bag, "--gains", gains, "--adapter", "dc_motor")
    assert code == 2
    assert "designed for plant my_motor, which is not a shipped plant" in err
    assert "--system PLANT.yaml" in err, err


def test_bad_system_file_key_is_one_line(tmp_path):
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.errors import GainFileError
    from fd_monitor.model.gains import write_gain_doc

    doc = yaml.safe_load((CONFIG / "gains" / f"{GAINS}.yaml").read_text())
    doc["system"]["file"] = 3
    write_gain_doc(tmp_path / "g.yaml", doc)
    with pytest.raises(GainFileError, match=r"g.yaml: system.file: expected the plant file's "
                                            r"path"):
        load_gains(tmp_path / "g.yaml")



# -- evaluate: the motor's own scenarios on the identified motor's gain file -----------------


def test_evaluate_runs_a_plants_scenarios_on_its_identified_models_gain_file(capsys):
    # dc_motor_* scenarios simulate dc_motor (the truth); the shipped gain file is for
    # dc_motor_identified (same inputs, outputs and sample time): its monitor reads them
    code, out, err = _cli(capsys, "evaluate", GAINS, "-s", "dc_motor_nominal", "-s",
                          "dc_motor_bias_velocity", "-s", "dc_motor_actuator", "--runs", 3,
                          "--no-progress", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["plant"] == "dc_motor_identified" and doc["simulated"] == ["dc_motor"]
    rows = {r["scenario"]: r for r in doc["rows"]}
    assert rows["dc_motor_nominal"]["false_alarm_rate"] == 0.0
    # 0.1 rad/s bias and 0.2 N m of effort lost at 30 s: detected in every run within 1 s
    # (doc/tutorial/own-robot.md, the worked example: delay 0 and 1 samples)
    for name in ("dc_motor_bias_velocity", "dc_motor_actuator"):
        r = rows[name]
        assert r["false_alarm_rate"] == 0.0 and r["detection_rate"] == 1.0, r
        assert r["delay_max_s"] <= 1.0, r


def test_evaluate_refuses_a_gain_file_of_another_plant(capsys):
    code, _out, err = _cli(capsys, "evaluate", GAINS, "-s", "three_tank_nominal", "--runs", 1,
                           "--no-progress")
    assert code == 2
    assert err.count("\n") == 1, err
    assert ("designed for dc_motor_identified, scenario three_tank_nominal is for three_tank, "
            "and their inputs differ") in err, err


# -- validate: an adapter file on its own, and a dry run over a bag --------------------------


@pytest.mark.parametrize("adapter", sorted(SHIPPED))
def test_validate_recognises_a_shipped_adapter_file(capsys, adapter):
    path = CONFIG / "adapters" / f"{adapter}.yaml"
    code, out, err = _cli(capsys, "validate", path)      # was "name: expected the plant's name"
    assert code == 0, err
    assert out.startswith(f"valid adapter {path}:"), out
    code, out, err = _cli(capsys, "validate", adapter, "--adapter", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["valid"] and doc["clock_topic"] == JOINT_STATES
    assert {(c["channel"], c["role"]) for c in doc["channels"]} == {("effort", "input"),
                                                                    ("velocity", "output")}


@pytest.mark.parametrize("text, match", [
    ("outputs:\n  - {channel: velocity, topic: /js, type: sensor_msgs/JointState, joint: m,"
     " field: speed}\n",
     r"bad\.yaml: outputs\[0\]\.field: 'speed' is not a field of sensor_msgs/msg/JointState"),
    ("outputs:\n  - {channel: velocity, topic: /js, type: sensor_msgs/Imu}\n",
     r"bad\.yaml: outputs\[0\]\.type: 'sensor_msgs/Imu': expected one of"),
    ("inputs: 3\noutputs: []\n", r"bad\.yaml: inputs: expected a list of channel mappings"),
    ("inputs:\n  - {channel: effort, topic: /c, type: std_msgs/Float64MultiArray}\n"
     "outputs:\n  - {channel: v, topic: /v, type: std_msgs/Float64}\n",
     r"bad\.yaml: inputs\[0\]: expected exactly one of label"),
])
def test_validate_a_bad_adapter_file_is_one_line_naming_the_key(tmp_path, capsys, text,
                                                                 match):
    bad = tmp_path / "bad.yaml"
    bad.write_text("format_version: 1\n" + text)
    code, out, err = _cli(capsys, "validate", bad)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("fd_monitor: error: "), err
    assert re.search(match, err), err


def test_validate_dry_run_shows_how_a_bag_pairs_into_samples(tmp_path, capsys):
    # 300 JointStates: the first has no command before it (skipped), the 101st is lost
    bag = _robot_bag(tmp_path, drop={(COMMANDS, 0), (JOINT_STATES, 100)})
    code, out, err = _cli(capsys, "validate", "dc_motor", "--adapter", "--bag", bag,
                          "--system", "dc_motor_identified", "--json")
    assert code == 0, err
    dry = json.loads(out)["dry_run"]
    assert dry["messages"] == {COMMANDS: 299, JOINT_STATES: 299}
    assert dry["sample_time"] == 0.01
    assert dry["sample_time_note"] == "sample time 0.01 s: the plant's (dc_motor_identified)"
    # 300 grid samples: k 0 has no command yet, k 100 lost its JointState (outputs are not
    # held): 298 used
    assert (dry["samples_present"], dry["samples_used"]) == (300, 298)
    assert (dry["k_first"], dry["k_last"]) == (0, 299)
    assert dry["gaps"] == [
        {"reason": "no_value", "channel": "effort", "first": 0, "last": 0, "samples": 1},
        {"reason": "stale", "channel": "velocity", "first": 100, "last": 100, "samples": 1}]
    assert dry["counts"] == {"no_value": 1, "stale": 1} and dry["new_runs"] == []
    # each sample: the command in force at its JointState
    assert [f["k"] for f in dry["first_samples"]] == [1, 2, 3, 4, 5]
    code, out, err = _cli(capsys, "validate", CONFIG / "adapters" / "dc_motor.yaml",
                          "--bag", bag)
    assert code == 0, err
    assert "samples: 300 present (k 0..299), 298 used; 1 no_value, 1 stale" in out, out
    assert "stale     velocity: k 100..100 (1 sample)" in out, out
    assert "snapped to a round value" in out, out          # Ts from the stamps
    assert "clock (grid phase)  header.stamp  299" in out, out
    # a plant's channels that the file does not map, and --bag on a plant file
    code, _out, err = _cli(capsys, "validate", "dc_motor", "--adapter", "--system",
                           "three_tank")
    assert code == 2 and "inputs: no mapping for q1, q2, v13" in err
    code, _out, err = _cli(capsys, "validate", "three_tank", "--bag", bag)
    assert code == 2 and "--bag: only for an adapter file" in err


# -- record --adapter: the robot's topics and what the monitor said about them ---------------


@pytest.mark.ros
def test_record_adapter_records_robot_topics_fd_outputs_and_diagnostics(tmp_path, capsys):
    from ros_util import Proc, wait_graph

    from fd_monitor.wire.bag_scanner import bag_topics
    from fd_monitor.wire.topics import CHAIN_OUTPUTS, DIAGNOSTICS

    plant, bag, n = load_gains(GAINS, verify=False).system_name, tmp_path / "rec", 300
    fd = [t.absolute for t in CHAIN_OUTPUTS]
    monitor = Proc(["run", "monitor", "--ros-args", "-p", f"system:={plant}", "-p",
                    f"gains:={GAINS}", "-p", "adapter:=dc_motor", "-p",
                    "diagnostics_period:=0.2"])
    # no TOPIC: the adapter's topics, fd/* and /diagnostics (it recorded the robot's only)
    rec = Proc(["record", "--adapter", "dc_motor", "-o", str(bag), "--until",
                f"{JOINT_STATES}={n}", "--until", f"/fd/alarm={n}", "--until",
                f"{DIAGNOSTICS.absolute}=1"])
    with monitor, rec:
        assert wait_graph([*fd, DIAGNOSTICS.absolute], 60.0, nodes=["monitor"]), \
            (monitor.output(), rec.output())
        # the simulated motor, 3 s paced at 4 x real time; it starts once the monitor and
        # the recorder subscribe its topics
        with Proc(["run", "plant_sim", "--ros-args", "-p", "scenario:=dc_motor_nominal",
                   "-p", "adapter:=dc_motor", "-p", "rate_factor:=4.0", "-p",
                   f"duration:={n / 100:.1f}", "-p", "min_subscribers_y:=2", "-p",
                   "min_subscribers_u:=2", "-p", "publish_truth:=false"]) as sim:
            assert sim.wait(120) == 0, sim.output()
            assert rec.wait(120) == 0, (rec.output(), monitor.output())
    topics = bag_topics(bag)
    assert topics[JOINT_STATES] == ("sensor_msgs/msg/JointState", n), topics
    assert topics[COMMANDS] == ("std_msgs/msg/Float64MultiArray", n), topics
    assert topics["/fd/alarm"][1] == n and topics["/fd/residual"][1] >= n - 1, topics
    assert topics[DIAGNOSTICS.absolute][1] >= 1, topics
    assert not any(t.startswith("/plant/") for t in topics), topics
    # the recorded bag through the same adapter: every sample, no alarm (fault free)
    code, out, err = _cli(capsys, "analyze", bag, "--gains", GAINS, "--adapter", "dc_motor",
                          "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["samples"] == n and doc["alarms"] == [], (doc["samples"], doc["alarms"])
    code, out, err = _cli(capsys, "report", bag, "--gains", GAINS, "--adapter", "dc_motor",
                          "-o", tmp_path / "report", "--json")
    assert code == 0, err
    assert json.loads(out)["alarms"] == []


def test_evaluate_refuses_a_model_with_another_sample_time(tmp_path, capsys):
    # a model of the motor at Ts = 0.02 s: its plant file is found from its gain file
    # (system.file), and it is not a model of dc_motor (Ts 0.01 s)
    plant = _own_plant(tmp_path)
    plant.write_text(plant.read_text().replace("\nsample_time: 0.01\n", "\nsample_time: 0.02\n"))
    gains = tmp_path / "g.yaml"
    code, _out, err = _cli(capsys, "design", "thresholds", plant, "--envelope", "declared",
                           "-o", gains)
    assert code == 0, err
    code, _out, err = _cli(capsys, "evaluate", gains, "-s", "dc_motor_nominal", "--runs", 1,
                           "--no-progress")
    assert code == 2 and err.count("\n") == 1, err
    assert ("designed for my_motor, scenario dc_motor_nominal is for dc_motor, and their "
            "sample times differ (my_motor: 0.02, dc_motor: 0.01)") in err, err
