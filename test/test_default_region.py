"""Safe by default (issue 23, item 4): the default gain file of every node and of the demo
states the region its guarantee covers, a fault-free run inside it raises no alarm, and an
alarm outside it (or after the run has left it) is marked ``outside_certified_region``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fd_monitor.analysis.summary import region_mark
from fd_monitor.commands.analyze import analyze_arrays
from fd_monitor.commands.demo import _gains as demo_gains
from fd_monitor.core.envelope import CertifiedRegion
from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import parse_scenario
from fd_monitor.model.system import load_system
from fd_monitor.model.yaml_io import read_yaml
from fd_monitor.nodes.chain_params import COMMON_PARAMS

CONFIG = Path(__file__).parents[1] / "config"


def _default_gain_files(tmp_path: Path) -> dict[str, str]:
    """Where each default comes from -> the gain file it names."""
    out = {"node parameter 'gains'": next(p.default for p in COMMON_PARAMS
                                          if p.name == "gains")}
    for f in sorted(CONFIG.glob("*.yaml")):
        for node, body in read_yaml(f).items():
            gains = body.get("ros__parameters", {}).get("gains")
            if gains is not None:
                out[f"{f.name}: {node}"] = gains
    out["demo"] = str(demo_gains(tmp_path, {}))
    return out


def test_every_default_gain_file_states_its_certified_region(tmp_path):
    """Fails when a default gain file (node parameter, shipped parameter file, demo) has no
    ``results.envelope``: its alarms could not be marked outside the certified region."""
    defaults = _default_gain_files(tmp_path)
    assert len(defaults) >= 7, defaults       # the parameter, 5 + 4 parameter-file nodes, demo
    for where, name in defaults.items():
        gf = load_gains(name)
        system = load_system(gf.system_name)
        region = CertifiedRegion.from_results(system, gf.results)
        assert region is not None, f"{where}: default gain file {name} states no region"
        assert runtime_for(system, gf).region_names, where
        # a region that certifies something: non-empty boxes in every mode
        assert np.all(region.state_hi > region.state_lo), where


def _pi(out: str, ref: float) -> dict:
    return {"pi": {"output": out, "reference": {"steps": [[0.0, ref]]}, "kp": 2.0e-3,
                   "ki": 2.0e-5, "min": 0.0, "max": 1.5e-4}}


AT_BOUNDS = {"noise": {"scale": 1.0, "distribution": "extreme"},
             "uncertainty": {"scale": 1.0, "distribution": "extreme"}}


def test_fault_free_inside_the_region_no_alarm_outside_every_alarm_marked():
    """Default gain file, noise and modelling uncertainty at their bounds (every sample at a
    vertex). Set points h1 = 0.48 m, h2 = 0.2 m (valve closed; not a design scenario's,
    inside the stored region): the run stays inside and raises no alarm. Pump 1 off with the
    bypass open from h1 = h3 = 0.25 m (levels below the region, h1 ~ h3 where the Torricelli
    root is stiff): it raises alarms, and every one is marked outside."""
    system = load_system("three_tank")
    gf = load_gains("three_tank_thresholds", system)
    inside = parse_scenario({
        "name": "inside", "system": "three_tank", "duration": 200.0, "seed": 7,
        "inputs": {"q1": _pi("h1", 0.48), "q2": _pi("h2", 0.2), "v13": {"steps": [[0.0, 0.0]]}},
        **AT_BOUNDS}, system=system)
    tr = simulate(inside, 7)
    assert not runtime_for(system, gf).run(tr.k, tr.u[0], tr.y[0]).outside.any()
    assert analyze_arrays(system, gf, tr.k, tr.u[0], tr.y[0])["alarms"] == []

    outside = parse_scenario({
        "name": "outside", "system": "three_tank", "duration": 30.0, "seed": 1,
        "initial": {"mode": "open_dry", "state": [0.25, 0.19, 0.25]},
        "inputs": {"q1": {"steps": [[0.0, 0.0]]}, "q2": {"steps": [[0.0, 4.5e-5]]},
                   "v13": {"steps": [[0.0, 1.0]]}}, **AT_BOUNDS}, system=system)
    tr = simulate(outside, 1)
    alarms = analyze_arrays(system, gf, tr.k, tr.u[0], tr.y[0])["alarms"]
    assert alarms, "expected false alarms at equal levels below the region"
    assert all(a["outside_certified_region"] for a in alarms)
    assert all("h1 below by" in a["outside_detail"] for a in alarms)


def test_an_alarm_after_an_excursion_is_marked_until_the_monitor_restarts():
    """The monitor's memory (filter window, mode, a bias estimate started outside) carries an
    excursion: an alarm inside the box after leaving it is not covered; a restart clears it."""
    out = np.zeros((100, 2))
    out[10:20, 0] = 0.05                   # left the region at samples 10..19 (h1 above)
    out[15, 0] = 0.08
    none = np.zeros(0, dtype=int)
    marked, worst, at = region_mark(out, none, 50, 55)
    assert marked and at == 15 and worst.tolist() == [0.08, 0.0]
    marked, worst, at = region_mark(out, none, 12, 17)           # during the excursion
    assert marked and at == 15
    marked, worst, at = region_mark(out, none, 2, 5)             # before it: inside
    assert not marked and not worst.any()
    assert region_mark(out, np.array([30]), 50, 55)[0] is False   # restarted at 30
    assert region_mark(out, np.array([5]), 50, 55)[0] is True     # restarted before it


def test_user_set_points_no_alarm_episode_inside_the_region():
    """Two set points of the user-set-point campaign of doc/theory/thresholds.md
    (benchmarks/campaign_envelope.py,
    seeds 2048 and 2049: 10 fault-free runs of 300 s, noise and uncertainty at their bounds)
    where the default file raises false alarms long after the plant came back inside its box
    (a bias estimate started by an earlier alarm outside): every alarm episode is marked by
    ``analyze``'s rule, none is inside."""
    import importlib.util

    from fd_monitor.analysis.summary import episodes
    from fd_monitor.core.monitor import run_batch
    from fd_monitor.core.simulator import simulate_batch

    spec = importlib.util.spec_from_file_location(
        "campaign_envelope", Path(__file__).parents[1] / "benchmarks" / "campaign_envelope.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    system = load_system("three_tank")
    gf = load_gains("three_tank_thresholds", system)
    region = CertifiedRegion.from_results(system, gf.results)
    marked = inside = late = 0
    for i in (48, 49):
        tr = simulate_batch(mod.envelope_scenario(system, 2000 + i),
                            [2000 + 1000 * i + j for j in range(5)])
        res = run_batch(system, gf, tr, keep=("x_hat", "mode"))
        ex = region.excess(res.mode_hat, res.x_hat, tr.u)
        for r in range(5):
            for c in range(3):
                for a, b in episodes(res.alarm[r, :, c]):
                    out, _, at = region_mark(ex[r], np.zeros(0, dtype=int), a, b)
                    marked += out
                    inside += not out
                    late += out and at < a
    assert marked > 0 and inside == 0
    assert late > 0, "expected alarms marked only for an excursion before them"
