"""Bounded-memory ``analyze`` and ``simulate`` (issue 24 item 4): the same results in chunks.

The contract reader (:func:`fd_monitor.analysis.reader.read_pass`) reads a bag in batches of
records, releases in-step samples without buffering them
(:meth:`~fd_monitor.wire.join.StampJoin.release_complete`), and
:func:`~fd_monitor.analysis.offline.run_bag` stacks the runtime's outputs in chunks (all of
them, or only what ``analyze`` reads). With batches and chunks of 7 (every boundary case: an
alarm episode, a hole, a region excursion across two chunks) both must give the run of the
whole bag read at once, message by message through the join, bit for bit; ``simulate`` writes
its bag in chunks and must write the same bytes. Memory and time against the bag's length:
``benchmarks/bench_analyze_memory.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fd_monitor.analysis import generate, offline, reader
from fd_monitor.analysis.offline import run_bag
from fd_monitor.analysis.summary import SparseRows, analyze_run, region_mark
from fd_monitor.core.methods import load_gains
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import gain_system

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("bag,gains", [
    ("three_tank_bad_input", "three_tank_thresholds"),        # input errors, holes, restarts
    ("three_tank_envelope_bias_h1", "three_tank_envelope"),   # alarms outside the region
    ("farhat_koenig_fault", "farhat_koenig_hminus_switched"),  # a side signal (mode)
])
def test_chunked_reading_equals_the_whole_bag_read_at_once(bag, gains, monkeypatch):
    path = REPO / "bags" / bag
    system = gain_system(load_gains(gains, verify=False))
    gf = load_gains(gains, system)
    with monkeypatch.context() as m:             # one batch, one chunk, no in-step release
        m.setattr(reader, "BATCH", 10 ** 9)
        m.setattr(offline, "CHUNK", 10 ** 9)
        m.setattr(reader, "_in_step", lambda *a: False)
        whole = run_bag(path, gf, system=system)
    ref = analyze_run(whole)
    monkeypatch.setattr(reader, "BATCH", 7)
    monkeypatch.setattr(offline, "CHUNK", 7)
    got = analyze_run(run_bag(path, gf, system=system, keep="summary"))
    assert json.dumps(got, sort_keys=True) == json.dumps(ref, sort_keys=True)
    assert got["samples"] > 0 and (got["alarms"] or got["input_errors"])
    full = run_bag(path, gf, system=system)
    for name in ("k", "signal", "threshold", "alarm", "mode_hat"):
        assert np.array_equal(getattr(full, name), getattr(whole, name)), name
    for name, v in whole.traces.items():
        assert np.array_equal(full.traces[name], v) and full.traces[name].dtype == v.dtype
    assert np.array_equal(full.truth.values, whole.truth.values, equal_nan=True)
    assert full.integrity == whole.integrity and full.inputs == whole.inputs


def test_sparse_region_marks_equal_the_dense_ones():
    rng = np.random.default_rng(3)
    dense = np.zeros((60, 2))
    rows = rng.choice(60, 12, replace=False)
    dense[rows] = rng.normal(size=(12, 2))
    dense[rows[0]] = dense[rows[1]]                      # a tie: the first one wins
    nz = np.flatnonzero(np.any(dense != 0.0, axis=1))
    sparse = SparseRows(nz, dense[nz], 60, 2)
    starts = np.array([10, 31])
    for a in range(60):
        for b in range(a, min(a + 9, 60)):
            o1, w1, at1 = region_mark(dense, starts, a, b)
            o2, w2, at2 = region_mark(sparse, starts, a, b)
            assert (o1, at1) == (o2, at2) and np.array_equal(w1, w2), (a, b)


@pytest.mark.parametrize("name,samples", [("three_tank_lpv_abrupt", 20),
                                          ("farhat_koenig_nominal", 33)])
def test_simulate_in_chunks_writes_the_same_bytes(name, samples, tmp_path):
    sc = load_scenario(name)
    generate._write(tmp_path / "whole", generate.simulated_messages(sc, 5, samples))
    generate._simulate_streaming(tmp_path / "chunks", sc, 5, samples, chunk=7)
    assert (tmp_path / "whole" / "whole.mcap").read_bytes() == \
        (tmp_path / "chunks" / "chunks.mcap").read_bytes()


@pytest.fixture(scope="module")
def robot_bag(tmp_path_factory):
    """A dc_motor robot's bag (JointState y, Float64MultiArray u), 2 s at 100 Hz."""
    from fd_monitor.commands.simulate import simulate_to_bag

    bag = tmp_path_factory.mktemp("robot") / "robot"
    simulate_to_bag("dc_motor_bias_velocity", bag, duration=2.0, adapter="dc_motor")
    return bag


def test_adapter_bag_out_of_log_time_order_reads_as_sorted(robot_bag, tmp_path):
    """A recorder under a backlog writes one topic's queue after the other's: records out of
    log-time order. The bounded reorder (:func:`~fd_monitor.wire.adapters.adapted_events`)
    gives the samples of the bag written in log-time order."""
    from fd_monitor.wire.adapters import load_adapter, read_adapted
    from fd_monitor.wire.bag_scanner import read_raw
    from fd_monitor.wire.bag_writer import BagWriter

    ad = load_adapter("dc_motor")
    recs = list(read_raw(robot_bag))
    u_topic = ad.inputs[0].topic
    out = tmp_path / "backlog"
    with BagWriter(out) as w:
        for i in range(0, len(recs), 60):              # each 60 records: u's queue last
            block = recs[i:i + 60]
            for topic, ty, t, raw in ([r for r in block if r[0] != u_topic]
                                      + [r for r in block if r[0] == u_topic]):
                w.add_topic(topic, ty)
                w.write_raw(topic, t, raw)
    assert [r[2] for r in read_raw(out)] != sorted(r[2] for r in read_raw(out))
    a, b = read_adapted(robot_bag, ad), read_adapted(out, ad)
    for name in ("k", "u", "y", "t"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.gaps == b.gaps and a.errors == b.errors and len(a.k) == 200


def test_identify_adapter_reads_through_the_contract(robot_bag, tmp_path):
    """``identify --adapter`` (:func:`~fd_monitor.analysis.identify.load_dataset`) reads a
    robot's bag through the contract: its ``integrity`` record, and ``--strict`` refusing a
    bag whose metadata.yaml is gone (issue 26 item 1)."""
    import shutil

    from fd_monitor.analysis.identify import load_dataset
    from fd_monitor.model.errors import BagError

    got: dict = {}
    ds = load_dataset(robot_bag, adapter="dc_motor", integrity=got)
    assert got[str(robot_bag)]["clean"] and got[str(robot_bag)]["samples_used"] == 200
    assert ds.k.size == 200
    bag = tmp_path / "robot"
    shutil.copytree(robot_bag, bag)
    (bag / "metadata.yaml").unlink()
    with pytest.warns(UserWarning, match="no metadata.yaml"), \
            pytest.raises(BagError, match=r"not used whole \(--strict\): metadata.yaml"):
        load_dataset(bag, adapter="dc_motor", strict=True)
