"""A fleet's bags and a campaign's chunks on Dask (issue 24; doc/howto/fleet.md).

Two clusters for the module, started once: the embedded LocalCluster of one worker (as the
commands start it) and a real ``dask scheduler`` with two ``dask worker`` processes, which
boot while the first works. What must hold: many-bag ``analyze`` gives the same tables with 1 and 2
workers as the single-bag ``analyze --json`` of each bag one by one; a corrupt bag among
them is one row with its error; ``evaluate``'s chunks give identical figures in this process
and with 1 and 2 workers; and both run through ``--scheduler`` on a real ``dask scheduler``
with two ``dask worker`` processes.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from fd_monitor.analysis.evaluate import run_campaign
from fd_monitor.analysis.evaluate_dask import run_campaign_on
from fd_monitor.analysis.fleet import (
    FleetMap,
    FleetTables,
    alarm_rows,
    bag_identity,
    bag_row,
    fleet_report,
    fleet_summary,
    read_tables,
)
from fd_monitor.analysis.scaleout import (
    LEAN_CONFIG,
    guided_batches,
    open_client,
    run_tasks,
)
from fd_monitor.commands.analyze import analyze_bag
from fd_monitor.commands.cli import main
from fd_monitor.commands.fleet import (
    analyze_fleet,
    analyze_task,
    fleet_jobs,
    load_gains_cached,
)
from fd_monitor.core.methods import load_gains
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.scenario import load_scenario

pytest.importorskip("distributed")

REPO = Path(__file__).resolve().parent.parent
#: bag -> robot folder it is put in; the gain file comes from the fleet map, by robot
BAGS = {"farhat_koenig_fault": "robot_a", "thesis_4_7_overlap": "robot_b",
        "three_tank_envelope_bias_h1": "robot_c"}
MAP = """format_version: 1
rules:
  - match: {robot: robot_a}
    gains: farhat_koenig_hminus_switched
  - match: {robot: robot_b}
    gains: thesis_4_7_hinf_sc
"""
GAINS = "three_tank_envelope"     # --gains: robot_c, no rule


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Three library bags in robot folders, and a corrupt one of robot_b."""
    root = tmp_path_factory.mktemp("fleet")
    for name, robot in BAGS.items():
        shutil.copytree(REPO / "bags" / name, root / robot / name,
                        ignore=shutil.ignore_patterns("expected.yaml"))
    broken = root / "robot_b" / "broken"
    shutil.copytree(REPO / "bags" / "farhat_koenig_fault", broken)
    (broken / "farhat_koenig_fault.mcap").write_bytes(b"not an mcap file " * 64)
    (root / "fleet_map.yaml").write_text(MAP, encoding="utf-8")
    return root


def _one_by_one(root, capsys):
    """The rows of each good bag from its own single-bag ``analyze --json``, through the
    tables' schema (as Parquet gives them back)."""
    import pyarrow as pa

    from fd_monitor.analysis.fleet import alarm_schema, bag_schema

    fm = FleetMap.load(root / "fleet_map.yaml")
    bags, alarms = [], []
    for name, robot in BAGS.items():
        bag = root / robot / name
        ident = bag_identity(bag)
        rule = fm.choose(str(bag), ident["robot"], ident["custom_data"])
        capsys.readouterr()
        assert main(["analyze", str(bag), "--gains", rule.gains if rule else GAINS,
                     "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        bags.append(bag_row(doc, ident))
        alarms += alarm_rows(doc, ident)
    bags = pa.Table.from_pylist(bags, schema=bag_schema()).to_pylist()
    alarms = pa.Table.from_pylist(alarms, schema=alarm_schema()).to_pylist()
    return (sorted(bags, key=lambda r: r["bag"]),
            sorted(alarms, key=lambda r: (r["bag"], r["first_sample"], r["channel"])))


def jobs_of(fleet):
    """The fleet's jobs (the corrupt bag included)."""
    return fleet_jobs([str(fleet)], GAINS, analyze_bag,
                      fleet_map=FleetMap.load(fleet / "fleet_map.yaml"))


def _short_scenarios(tmp_path):
    """pwa_cascade scenarios of 4 s (400 samples): fault free, and b1 +0.5 at 2 s."""
    (tmp_path / "nom.yaml").write_text("name: short_nominal\nsystem: pwa_cascade\n"
                                       "duration: 4.0\nseed: 1\n", encoding="utf-8")
    (tmp_path / "b1.yaml").write_text(
        "name: short_b1\nsystem: pwa_cascade\nduration: 4.0\nseed: 1\nfaults:\n"
        "  - {channel: b1_step, profile: abrupt, time: 2.0, magnitude: 0.5}\n",
        encoding="utf-8")
    return [load_scenario(str(tmp_path / "nom.yaml")), load_scenario(str(tmp_path / "b1.yaml"))]


CAMPAIGN = {"chunk": 2, "rhos": [0.05, 1.0], "progress": False}
RUNS = 6


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def dask_cluster():
    """A real ``dask scheduler`` and two ``dask worker`` processes on localhost, started at
    once (they boot while the embedded cluster works); its address."""
    dask = str(Path(sys.executable).parent / "dask")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    # the embedded cluster's quiet settings (LEAN_CONFIG), as Dask reads them from the
    # environment: the three processes idle while the embedded cluster works
    env = dict(os.environ, OMP_NUM_THREADS="1",
               **{"DASK_" + k.upper().replace(".", "__").replace("-", "_"): str(v)
                  for k, v in LEAN_CONFIG.items()})
    quiet = {"env": env, "cwd": REPO, "stdout": subprocess.DEVNULL,
             "stderr": subprocess.DEVNULL}
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard", "--dashboard-address", "127.0.0.1:0"],
                              **quiet)]
    try:
        # the workers retry until the scheduler listens
        procs += [subprocess.Popen([dask, "worker", addr, "--nthreads", "1", "--no-nanny",
                                    "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
                                    "--name", f"w{i}"], **quiet)
                  for i in range(2)]
        yield addr
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:   # a worker slow to close on a loaded
                p.kill()                        # machine: its results are in already
                p.wait(timeout=30)


@pytest.fixture(scope="module")
def one_worker(fleet, tmp_path_factory, dask_cluster):
    """The fleet's tables and the short campaign's rows on the embedded cluster of one
    worker (:func:`open_client`, as the commands start it; the API :func:`analyze_fleet`
    with all four bags in one batch, :func:`run_campaign_on`)."""
    out = tmp_path_factory.mktemp("w1")
    jobs = jobs_of(fleet)
    with open_client(1) as client:
        run, tables = analyze_fleet(client, jobs, out / "tables", per_worker=1)
        rows, done = run_campaign_on(client, load_gains("pwa_cascade_qb"),
                                     _short_scenarios(out), RUNS, **CAMPAIGN)
        # Ctrl-C (KeyboardInterrupt in the result loop) after the first bag: the rest is
        # cancelled, the tables closed with that bag
        with FleetTables(out / "stopped") as partial:
            def first_then_stop(_i, r):
                partial.add(r["row"], r["alarms"])
                raise KeyboardInterrupt
            stop = run_tasks(client, analyze_task, jobs, first_then_stop)
    return run, tables, rows, done, stop, partial


@pytest.fixture(scope="module")
def two_workers(fleet, tmp_path_factory, one_worker, dask_cluster):
    """The same through the command line's ``--scheduler`` on the real cluster's two
    workers (one bag a batch): ``analyze --json`` and ``evaluate --json`` documents, and
    the tables folder."""
    from distributed import Client

    out = tmp_path_factory.mktemp("w2")
    with Client(dask_cluster, timeout="60s") as c:
        c.wait_for_workers(2, timeout=60)
    docs = []
    for argv in (["analyze", str(fleet), "--gains", GAINS, "--map",
                  str(fleet / "fleet_map.yaml"), "--out", str(out / "tables"),
                  "--no-progress"],
                 ["evaluate", "pwa_cascade_qb", "--runs", str(RUNS), "--chunk", "2",
                  "--rho", "0.05,1", "--no-progress",
                  *[a for sc in _short_scenarios(out) for a in ("-s", sc.source)]]):
        with contextlib.redirect_stdout(io.StringIO()) as buf:
            assert main([*argv, "--scheduler", dask_cluster, "--json"]) == 0
        docs.append(json.loads(buf.getvalue()))
    return out / "tables", docs[0], docs[1]


def test_guided_batches_cover_every_item_once_and_end_with_single_items():
    for n, w in ((1, 1), (4, 1), (4, 2), (200, 2), (10_000, 2), (10_000, 100), (7, 16)):
        batches = guided_batches(n, w)
        assert [i for b in batches for i in b] == list(range(n))
        sizes = [len(b) for b in batches]
        assert sizes == sorted(sizes, reverse=True) and max(sizes) <= 16
        assert sizes[-min(n, w):] == [1] * min(n, w)        # the workers finish together
    # many more bags than workers: far fewer tasks than bags
    assert len(guided_batches(10_000, 2)) < 700 and len(guided_batches(200, 2)) == 30
    assert [len(b) for b in guided_batches(4, 1, per_worker=1)] == [4]


def test_gain_file_loaded_once_per_worker_and_again_after_an_edit(tmp_path):
    src = REPO / "config" / "gains" / "three_tank_thresholds.yaml"
    g = tmp_path / "g.yaml"
    g.write_bytes(src.read_bytes())
    first = load_gains_cached(str(g))
    assert load_gains_cached(str(g)) is first                # the same objects: not reloaded
    assert first[0].certificate_status == "verified" and first[1].name == "three_tank"
    g.write_bytes(src.read_bytes() + b"# edited\n")          # another digest: loaded again
    again = load_gains_cached(str(g))
    assert again is not first and again[0].method == first[0].method
    g.write_bytes(src.read_bytes().replace(b"method: thresholds", b"method: threshold"))
    with pytest.raises(FdMonitorError):                      # a failure is not cached
        load_gains_cached(str(g))


def test_many_bags_1_and_2_workers_equal_one_by_one_and_a_corrupt_bag_is_a_row(
        one_worker, two_workers, fleet, tmp_path, capsys):
    run1, t1, _r, _d, stop, partial = one_worker
    folder2, doc2, _ev = two_workers
    assert (run1.workers, run1.done, run1.total, run1.stopped) == (1, 1, 1, False)  # 1 batch
    assert (stop.stopped, stop.done, stop.total) == (True, 0, 4)   # stopped in the 1st callback
    kept, _a = read_tables(partial.folder)
    assert partial.bags == 1 and len(kept) == 1 and kept[0]["bag"] in {j["name"] for j in
                                                                       jobs_of(fleet)}
    assert (doc2["workers"], doc2["bags"], doc2["errors"], doc2["stopped"]) == (2, 4, 1, False)
    b1, a1 = read_tables(t1.folder)
    b2, a2 = read_tables(folder2)
    assert b1 == b2 and a1 == a2
    # the corrupt bag: one row, its error, nothing else
    bad = [b for b in b1 if b["error"] is not None]
    assert len(bad) == 1 and bad[0]["bag"].endswith("broken") and bad[0]["robot"] == "robot_b"
    assert "not an MCAP file" in bad[0]["error"] and bad[0]["samples"] is None
    assert (t1.errors, t1.bags) == (1, 4)
    # every other row is exactly what the single-bag analyze --json of that bag gives
    good = [b for b in b1 if b["error"] is None]
    ob, oa = _one_by_one(fleet, capsys)
    assert good == ob and a1 == oa
    assert {b["robot"] for b in good} == set(BAGS.values())
    assert all(b["alarms"] >= 1 and b["samples"] > 0 for b in good), good
    # the summary (as printed) and the fleet page read the same tables
    s = fleet_summary(b1, a1)
    assert doc2["robots"] == s["robots"] and doc2["days"] == s["days"]
    per = {r["robot"]: r for r in s["robots"]}
    assert (per["robot_b"]["bags"], per["robot_b"]["errors"]) == (2, 1)
    assert sum(d["episodes"] for d in s["days"]) == len(a1)
    rep = fleet_report(t1.folder, tmp_path / "page")
    md = Path(rep["summary_md"]).read_text()
    assert "robot_a" in md and "not an MCAP file" in md
    assert Path(rep["figures"]["alarms_over_time"]).stat().st_size > 1000


def test_evaluate_in_process_1_and_2_workers_identical(one_worker, two_workers, tmp_path):
    ref = run_campaign(load_gains("pwa_cascade_qb"), _short_scenarios(tmp_path), RUNS,
                       **CAMPAIGN)
    _run, _t, one, done1, _s, _p = one_worker
    _f, _doc, ev2 = two_workers
    assert (done1.workers, done1.done, done1.stopped) == (1, 6, False)
    assert [(r.as_dict(), r.delays.tolist()) for r in one] == \
        [(r.as_dict(), r.delays.tolist()) for r in ref]
    assert ev2["rows"] == [r.as_dict() for r in ref]        # JSON floats: exact
    # the figures mean something: b1 detected in every run; thresholds scaled by 0.05 alarm
    # in every run, fault or not
    by = {(r.scenario, r.rho): r for r in ref}
    assert by[("short_b1", 1.0)].detection_rate == 1.0
    assert by[("short_nominal", 0.05)].false_alarm_rate == 1.0
