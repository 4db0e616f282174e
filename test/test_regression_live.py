"""Regression suite through the live nodes: replay library bags into the running monitor.

The live subset of ``bags/library.yaml`` (``live: true``) is replayed flat out (lossless) into
the ``monitor`` process (the four chain nodes on one executor) and into the five-process
pipeline (observer, detector, agei, bias_estimator and replay), the outputs are recorded, and
the same ``expected.yaml`` is checked on what the nodes published.
"""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import Proc, run_cli

from fd_monitor.bags import read_bag
from fd_monitor.library import check_expected, load_expected, load_library

pytestmark = pytest.mark.ros

LIB = load_library()
LIVE = [b.name for b in LIB.bags if b.live]
TOPICS = ["/fd/alarm", "/fd/state_estimate", "/fd/bias_estimate"]


def live_summary(rec, system_outputs, mode_names):
    """The analyze-style summary of what the nodes published (recorded bag ``rec``)."""
    got = read_bag(rec, TOPICS)
    al, st, be = got["/fd/alarm"], got["/fd/state_estimate"], got["/fd/bias_estimate"]
    alarms = []
    for c in system_outputs:
        hits = np.flatnonzero(al.column(c) > 0.5)
        if hits.size:
            alarms.append({"channel": c, "first_sample": int(al.stamps[hits[0]])})
    modes = []
    for q in st.column("mode"):
        name = mode_names[int(q)]
        if not modes or modes[-1] != name:
            modes.append(name)
    return {"alarms": alarms, "modes": modes, "samples": len(al),
            "isolated": [c for c in system_outputs if be.column(f"iso:{c}")[-1] > 0.5],
            "bias_estimate": {c: float(be.column(c)[-1]) for c in system_outputs}}


@pytest.mark.parametrize(("name", "layout"), [(LIVE[0], "monitor"),
                                              (LIVE[-1], "five_processes")])
def test_live_nodes_match_expected(tmp_path, name, layout):
    from fd_monitor.system import load_system

    spec = LIB[name]
    assert spec.gains == "three_tank_thresholds"   # the nodes' default gain file
    system = load_system("three_tank")
    n = len(read_bag(spec.folder, ["/plant/y"])["/plant/y"])
    nodes = ["monitor"] if layout == "monitor" else ["observer", "detector", "agei",
                                                     "bias_estimator"]
    procs = [Proc(["run", x]) for x in nodes]
    until = [a for t in TOPICS for a in ("--until", f"{t}={n}")]
    rec = Proc(["record", *TOPICS, "-o", str(tmp_path / "rec"), *until])
    try:
        # /plant/u and /plant/y have two subscribers: the observer and the bias estimator.
        rep = run_cli(["replay", str(spec.folder), "--topics", "/plant/u", "/plant/y",
                       "--rate", "0", "--wait-subscribers", "2"], timeout=180)
        assert rep.returncode == 0, rep.stderr
        assert rec.wait(180) == 0, rec.output() + "".join(p.output()[-2000:] for p in procs)
    finally:
        for p in [rec, *procs]:
            p.stop()
    for p in procs:
        assert "Traceback" not in p.output(), p.output()
    s = live_summary(tmp_path / "rec", system.outputs, system.mode_names)
    assert s["samples"] == n                       # no sample lost
    assert check_expected(load_expected(spec.expected_file), s) == []
