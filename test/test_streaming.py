"""Bounded-memory ``analyze`` and ``simulate`` (issue 24 item 4): the same results in chunks.

``analyze`` reads, steps and reduces a bag in chunks (:mod:`fd_monitor.analysis.streaming`)
and must give the document of the whole-bag path (:func:`~fd_monitor.analysis.offline.run_bag`
+ :func:`~fd_monitor.analysis.summary.analyze_run`) bit for bit, here with chunks of 7 so
every boundary case (an alarm episode, a hole, a region excursion across two chunks) is hit;
``simulate`` writes its bag in chunks and must write the same bytes. Memory and time against
the bag's length: ``benchmarks/bench_fleet.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fd_monitor.analysis import generate, streaming
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
    ("thesis_4_7_overlap", "thesis_4_7_hinf_sc"),
])
def test_streaming_analyze_equals_the_whole_bag_path(bag, gains, monkeypatch):
    path = REPO / "bags" / bag
    system = gain_system(load_gains(gains, verify=False))
    gf = load_gains(gains, system)
    ref = analyze_run(run_bag(path, gf, system=system))
    monkeypatch.setattr(streaming, "CHUNK", 7)
    got = streaming.analyze_streaming(path, gf, system)
    assert json.dumps(got, sort_keys=True) == json.dumps(ref, sort_keys=True)
    assert got["samples"] > 0 and (got["alarms"] or got["input_errors"])


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
