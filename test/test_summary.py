"""One result summary (analysis/summary.py), one bag writer, input errors classified by
exception class, one DDS environment set-up."""

from __future__ import annotations

import numpy as np
import pytest
from bag_compare import assert_bags_close

from fd_monitor.analysis.library import load_library
from fd_monitor.analysis.offline import run_bag
from fd_monitor.analysis.reader import classify as _classify
from fd_monitor.analysis.summary import (
    Outputs,
    episodes,
    mode_tracking,
    recorded_outputs,
    summarize,
    summarize_run,
    true_biases,
    truth_facts,
)
from fd_monitor.commands.simulate import simulate_to_bag
from fd_monitor.model.errors import (
    ImplausibleError,
    MessageError,
    NonFiniteError,
    WrongLengthError,
)
from fd_monitor.model.system import load_system
from fd_monitor.nodes.domain import isolate_env
from fd_monitor.wire.bag_reader import TopicArrays
from fd_monitor.wire.bag_writer import array_msg
from fd_monitor.wire.conversions import decode

LIB = load_library()


def test_episodes_are_the_true_runs():
    assert episodes(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == [(1, 2), (4, 4), (7, 7)]
    assert episodes(np.zeros(3, bool)) == []


def test_summarize_first_alarm_after_the_transient_isolation_and_modes():
    k = np.arange(10, 20)
    alarm = np.zeros((10, 2), bool)
    alarm[1, 0] = True          # sample 11: before the transient
    alarm[6:, 0] = True         # sample 16 on
    alarm[8, 1] = True          # sample 18
    out = Outputs(k=k, dt=0.5, channels=("a", "b"), alarm=alarm,
                  mode=np.array([0, 0, 1, 1, 1, 0, 0, 0, 0, 0]), mode_names=("q0", "q1"),
                  estimate={"a": np.linspace(0, 1, 10)},
                  isolated=np.column_stack([np.zeros(10, bool), np.ones(10, bool)]),
                  isolation_channels=("a", "b"), restarts=[15])
    s = summarize(out, transient=6.0)     # k >= 12
    assert s["alarms"] == [{"channel": "a", "first_sample": 16, "time": 8.0},
                           {"channel": "b", "first_sample": 18, "time": 9.0}]
    assert s["isolated"] == ["b"]
    assert s["bias_estimate"] == {"a": 1.0}
    assert s["modes"] == ["q0", "q1", "q0"]
    assert s["mode_segments"] == [["q0", 10, 2], ["q1", 12, 3], ["q0", 15, 5]]
    assert s["restarts"] == [15] and s["samples"] == 10
    # no isolation flags: an isolating channel that alarmed is isolated
    out.isolated, out.isolating = None, ("b",)
    assert summarize(out)["isolated"] == ["b"]


def test_mode_tracking_delays_and_untracked_transitions():
    q = np.array([0, 0, 1, 1, 1, 0, 0, 2, 2, 0])
    q_hat = np.array([0, 0, 0, 1, 1, 1, 1, 1, 1, 1])   # late to 1, never to 0 or 2
    m = mode_tracking(q, q_hat, 0.5)
    assert m == {"true": 4, "tracked": 1, "max_delay_s": 0.5, "mode_agreement": 0.4}
    assert mode_tracking(q, q, 0.5)["max_delay_s"] == 0.0


def test_recorded_outputs_read_by_label_not_by_position():
    """The live chain's topics, columns in another order than the plant's outputs: the
    summary is the same as with the columns in order."""
    system = load_system("three_tank")
    o = system.outputs
    n = 6
    k = np.arange(n)
    rng = np.random.default_rng(1)
    alarm = np.zeros((n, len(o)))
    alarm[3:, 1] = 1.0
    sigma = rng.normal(size=(n, len(o)))
    iso = np.zeros((n, len(o)))
    iso[-1, 1] = 1.0

    def arrays(topic, labels, values):
        return TopicArrays(topic, tuple(labels), k, np.asarray(values, float), k * 10)

    def topics(perm):
        be_labels = [*o, *(f"iso:{c}" for c in o)]
        be = np.hstack([sigma, iso])
        bperm = [*perm, *(len(o) + i for i in perm)]
        return {"/fd/alarm": arrays("/fd/alarm", [o[i] for i in perm], alarm[:, perm]),
                "/fd/state_estimate": arrays("/fd/state_estimate", ["restart", "mode"],
                                             np.column_stack([np.zeros(n), np.zeros(n)])),
                "/fd/bias_estimate": arrays("/fd/bias_estimate",
                                            [be_labels[i] for i in bperm], be[:, bperm])}

    straight = summarize(recorded_outputs(topics([0, 1, 2]), system))
    shuffled = summarize(recorded_outputs(topics([2, 0, 1]), system))
    assert shuffled == straight
    assert straight["alarms"] == [{"channel": o[1], "first_sample": 3,
                                   "time": round(3 * system.sample_time, 9)}]
    assert straight["isolated"] == [o[1]]
    assert straight["bias_estimate"] == {c: float(sigma[-1, i]) for i, c in enumerate(o)}


def test_summarize_run_and_truth_facts_of_a_library_bag():
    spec = LIB["three_tank_bias_h1"]
    run = run_bag(spec.folder, spec.gains, transient=spec.transient)
    s = summarize_run(run)
    assert s["isolated"] == ["h1"]
    facts = truth_facts(run.truth, run.system)
    (_name, f), = facts["faults"].items()
    assert f["target"] == "h1" and f["kind"] == "sensor_bias"
    assert s["alarms"][0]["first_sample"] >= f["onset_sample"]
    assert true_biases(facts) == {"h1": f["final"]}
    assert facts["samples"] == len(run.k)


def test_input_errors_are_classified_by_exception_class_not_by_text():
    # texts that the old substring rules would have misread
    assert _classify(MessageError("wrong length size non-finite")) == "malformed"
    assert _classify(NonFiniteError("x")) == "non_finite"
    assert _classify(WrongLengthError("x")) == "wrong_length"
    assert _classify(ImplausibleError("wrong length")) == "implausible"


def test_decode_raises_the_classes_the_offline_reader_classifies():
    ok = array_msg(("h1", "h2"), 3, [1.0, 2.0])
    with pytest.raises(WrongLengthError):
        decode(ok, "/plant/y", labels=("h1", "h2", "h3"))
    nan = array_msg(("h1", "h2"), 3, [1.0, 2.0])
    nan.data[2] = float("nan")
    with pytest.raises(NonFiniteError):
        decode(nan, "/plant/y", labels=("h1", "h2"))


def test_simulate_writes_the_library_bag(tmp_path):
    """One writer: ``simulate`` gives the library's bag for the same scenario, seed and
    duration (a bag without corruptions): metadata byte for byte, messages within rounding of
    the shipped ones (bag_compare.SIM_RTOL: the shipped bag was simulated on another
    machine)."""
    spec = LIB["three_tank_valve"]
    assert not spec.corruptions
    out = tmp_path / spec.name
    doc = simulate_to_bag(spec.scenario, out, spec.seed, spec.duration)
    assert doc["topics"][:2] == ["/plant/u", "/plant/y"] and doc["seed"] == spec.seed
    assert (out / "metadata.yaml").read_bytes() == (spec.folder / "metadata.yaml").read_bytes()
    assert_bags_close(out, spec.folder)


def test_isolate_env_localhost_and_its_domain():
    env = {"ROS_LOCALHOST_ONLY": "1", "ROS_DOMAIN_ID": "42"}
    assert isolate_env(env, keep_domain=True) is env
    assert env == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": "42",
                   "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
