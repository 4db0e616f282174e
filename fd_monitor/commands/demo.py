"""``python -m fd_monitor demo``: the whole pipeline on the default plant, end to end.

1. Use the shipped gain file of ``three_tank`` (``config/gains/three_tank_thresholds.yaml``),
   or design it (``python -m fd_monitor design thresholds three_tank``) if it is missing.
2. Start ``observer``, ``detector``, ``agei`` and ``bias_estimator`` as separate processes,
   and ``record``, on an isolated ROS_DOMAIN_ID (localhost discovery).
3. Start ``plant_sim`` on the scenario ``three_tank_bias_h1`` (400 s: PI level control,
   guard crossings both ways, a valve opening, and a +1 cm bias on sensor h1 injected at
   200 s), flat out without loss (``rate_factor: 0.0``).
4. Once every topic has every sample, stop everything cleanly and print the summary from the
   bag: detection time, isolated sensor, sigma-hat against the true bias, mode transitions
   tracked by the observer.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from fd_monitor.commands._common import add_json_flag, count, number, print_json, print_table
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.nodes.domain import die_with_parent
from fd_monitor.wire.topics import (
    ALARM,
    BIAS_ESTIMATE,
    CHAIN_DATA,
    DIAGNOSTICS,
    GUARD_EVENT,
    PLANT_TRUTH,
    RESIDUAL,
    STATE_ESTIMATE,
    THRESHOLD,
    THRESHOLD_OVERRIDE,
)

__all__ = ["add_arguments", "run", "summarize"]

FD_NODES = ("observer", "detector", "agei", "bias_estimator")
TOPICS = tuple(t.absolute for t in CHAIN_DATA)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--output, --scenario, --seed, --rate-factor, --timeout, --json."""
    parser.add_argument("--output", metavar="DIR", default=None,
                        help="folder for the bag, logs and gain file (default: a new "
                             "temporary folder)")
    parser.add_argument("--scenario", default="three_tank_bias_h1",
                        help="scenario (default three_tank_bias_h1)")
    parser.add_argument("--seed", type=count(0), default=None,
                        help="seed (default: the scenario's)")
    parser.add_argument("--rate-factor", type=number(0), default=0.0,
                        help="plant_sim pace: sample rate x this; 0 = flat out, lossless "
                             "(default)")
    parser.add_argument("--timeout", type=number(0, low_open=True), default=110.0,
                        help="s to wait for the run before giving up (default 110)")
    add_json_flag(parser)


class _Processes:
    """Child processes with logs, always stopped (SIGINT, then kill) at the end."""

    def __init__(self, env: dict[str, str], logs: Path) -> None:
        self.env, self.logs = env, logs
        self.procs: dict[str, subprocess.Popen] = {}
        logs.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, args: list[str]) -> subprocess.Popen:
        log = open(self.logs / f"{name}.log", "w")  # the child keeps its copy
        p = subprocess.Popen([sys.executable, "-m", "fd_monitor", *args], env=self.env,
                             stdout=log, stderr=subprocess.STDOUT, text=True,
                             preexec_fn=die_with_parent)
        log.close()
        self.procs[name] = p
        return p

    def failed(self) -> str | None:
        for name, p in self.procs.items():
            if p.poll() not in (None, 0):
                return f"{name} exited with status {p.returncode}: {self.tail(name)}"
        return None

    def tail(self, name: str) -> str:
        lines = (self.logs / f"{name}.log").read_text(errors="replace").strip().splitlines()
        return lines[-1] if lines else "(no output)"

    def stop_all(self, timeout: float = 10.0) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout
        for p in self.procs.values():
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


def _gains(out: Path, env: dict[str, str]) -> Path:
    from fd_monitor.model.paths import config_dirs

    for d in config_dirs():
        cand = d / "gains" / "three_tank_thresholds.yaml"
        if cand.is_file():
            return cand
    path = out / "three_tank_thresholds.yaml"
    r = subprocess.run([sys.executable, "-m", "fd_monitor", "design", "thresholds",
                        "three_tank", "-o", str(path)], env=env, capture_output=True,
                       text=True, timeout=600)
    if r.returncode != 0:
        raise FdMonitorError(f"demo: designing the gains failed: "
                             f"{(r.stderr or r.stdout).strip().splitlines()[-1:]}")
    return path


def _env(out: Path) -> dict[str, str]:
    from fd_monitor.nodes.domain import isolate_env
    from fd_monitor.nodes.pacing import use_dds_profile  # noqa: F401  (ROS present?)

    # Its own domain: a foreign node in it would feed the chain or count as a subscriber.
    env = dict(isolate_env(dict(os.environ)))
    env["ROS_LOG_DIR"] = str(out / "ros_logs")
    env["PYTHONUNBUFFERED"] = "1"
    root = Path(__file__).resolve().parents[2]
    if (root / "fd_monitor").is_dir():
        env["PYTHONPATH"] = str(root) + os.pathsep + env.get("PYTHONPATH", "")
    return env


#: Subscriptions per fd topic once the chain and record are up (consumers + record).
GRAPH = {t.absolute: n for t, n in ((STATE_ESTIMATE, 4), (RESIDUAL, 2), (THRESHOLD, 2),
                                    (ALARM, 2), (GUARD_EVENT, 3), (THRESHOLD_OVERRIDE, 2),
                                    (BIAS_ESTIMATE, 3))}


def _wait_for_graph(env: dict[str, str], timeout: float, procs: _Processes) -> bool:
    """Poll the ROS graph (in the demo's domain) until every fd topic has its publisher and
    its subscriptions and the counts have stayed the same for 0.5 s (what this probe sees
    comes before every publisher has matched every subscription: a data topic is volatile,
    a match that comes late misses the first samples); False on timeout or when a process
    failed."""
    import rclpy
    from rclpy.node import Node

    keys = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")
    old = {k: os.environ.get(k) for k in keys}
    os.environ.update({k: env[k] for k in keys})
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = Node("demo_graph", context=ctx)
        deadline = time.monotonic() + timeout
        last, since = None, time.monotonic()
        while time.monotonic() < deadline and procs.failed() is None:
            now = [(node.count_publishers(t), node.count_subscribers(t)) for t in GRAPH]
            if now != last:
                last, since = now, time.monotonic()
            elif all(p >= 1 and c >= n for (p, c), n in zip(now, GRAPH.values())) and \
                    time.monotonic() - since >= 0.5:
                return True
            time.sleep(0.05)  # polling the graph, not synchronising messages
        return False
    finally:
        rclpy.try_shutdown(context=ctx)
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run(args: argparse.Namespace) -> int:
    """Run the demo and print its summary."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        raise FdMonitorError("demo: needs ROS 2 (rclpy); install with pip install '.[ros]'") \
            from None
    from fd_monitor.model.scenario import load_scenario

    sc = load_scenario(args.scenario)
    if args.rate_factor < 0:
        raise FdMonitorError(f"--rate-factor {args.rate_factor}: expected >= 0")
    out = Path(args.output) if args.output else Path(tempfile.mkdtemp(prefix="fd_monitor_demo_"))
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    if bag.exists():
        raise FdMonitorError(f"demo: {bag} already exists (choose another --output)")
    env = _env(out)
    gains = _gains(out, env)
    K = sc.n_samples
    seed = sc.seed if args.seed is None else args.seed
    procs = _Processes(env, out / "logs")
    t0 = time.monotonic()
    try:
        for n in FD_NODES:
            # The distributed layout: four processes, the detector fed by the observer. The
            # run is flat out and lossless by design: a history that holds the whole run and
            # 5 s for late feedback keep a CPU-starved machine from turning delay into loss.
            procs.start(n, ["run", n, "--ros-args", "-p", f"gains:={gains}",
                            "-p", f"qos_depth:={min(1_000_000, max(1000, K + 100))}",
                            "-p", "gap_timeout:=5.0", "-p", "restart_after:=5.0"])
        until = [a for t in TOPICS for a in ("--until", f"{t}={K}")]
        rec = procs.start("record", ["record", *TOPICS, DIAGNOSTICS.absolute, "-o", str(bag),
                                     *until])
        # Data topics are volatile: a subscriber matched late misses the first samples, so
        # plant_sim starts only once the chain's and record's endpoints are in the graph.
        if not _wait_for_graph(env, min(60.0, args.timeout), procs):
            raise FdMonitorError(f"demo: the nodes did not all appear in the ROS graph (logs "
                                 f"in {out / 'logs'})")
        # /plant/u, /plant/y: observer, bias_estimator, record; /plant/truth: record.
        procs.start("plant_sim", [
            "run", "plant_sim", "--ros-args", "-p", f"scenario:={sc.source}",
            "-p", f"seed:={seed}", "-p", f"rate_factor:={float(args.rate_factor)}",
            # every sample, at any rate: a batch (a chain node behind sheds a live stream)
            "-p", "batch_mark:=always",
            "-p", "min_subscribers_u:=3", "-p", "min_subscribers_y:=3",
            "-p", "min_subscribers_truth:=1", "-p", "subscriber_timeout:=60.0"])
        while rec.poll() is None:
            failure = procs.failed()
            if failure:
                raise FdMonitorError(f"demo: {failure} (logs in {out / 'logs'})")
            if time.monotonic() - t0 > args.timeout:
                raise FdMonitorError(f"demo: not finished after {args.timeout:g} s (logs in "
                                     f"{out / 'logs'})")
            time.sleep(0.2)  # polling child processes, not synchronising messages
        if rec.returncode != 0:
            raise FdMonitorError(f"demo: record failed: {procs.tail('record')}")
    finally:
        procs.stop_all()
    wall = time.monotonic() - t0
    summary = summarize(bag, sc, gains)
    summary["wall_time_s"] = round(wall, 2)
    summary["output"] = str(out)
    summary["report"] = _report(bag, out / "report", gains)
    if args.json:
        print_json(summary)
    else:
        _print(summary)
    return 0


def _report(bag: Path, folder: Path, gains: Path) -> str | None:
    """The bag report's summary (figures and markdown); the demo's result stands without it."""
    try:
        from fd_monitor.analysis.report import bag_report

        return str(bag_report(bag, folder, gains)["summary_md"])
    except Exception as exc:  # the report is an extra: say why it is missing, keep the summary
        print(f"fd_monitor demo: warning: no report ({type(exc).__name__}: {exc})",
              file=sys.stderr)
        return None


def summarize(bag: str | Path, scenario: Any, gains: str | Path) -> dict[str, Any]:
    """The demo's summary from a recorded bag (works on any bag of the pipeline).

    Returns
    -------
    dict
        ``fault`` {channel, output, time, magnitude}, ``detected_at`` (s, or None),
        ``detection_delay`` (s), ``alarm_channels``, ``isolated`` (output names),
        ``bias_estimate`` {output: sigma-hat at the end}, ``true_bias``, ``transitions``
        {true, tracked}, ``samples`` {topic: count}, ``lost`` (samples missing).
    """
    from fd_monitor.analysis.summary import (
        mode_tracking,
        recorded_outputs,
        true_biases,
        truth_facts,
    )
    from fd_monitor.analysis.summary import summarize as summarize_outputs
    from fd_monitor.wire.bag_reader import read_bag

    b = read_bag(bag, list(TOPICS))
    sys_ = scenario.system
    dt = sys_.sample_time
    K = scenario.n_samples
    counts = {t: len(a) for t, a in b.items()}
    fault = None
    if scenario.faults:
        f = scenario.faults[0]
        ch = sys_.faults[f.channel]
        fault = {"channel": ch.name, "output": sys_.outputs[ch.index] if ch.index >= 0 else None,
                 "time": f.time, "magnitude": f.magnitude}
    out = recorded_outputs(b, sys_)
    s = summarize_outputs(out)
    first = min((a["first_sample"] for a in s["alarms"]), default=None)
    detected_at = None if first is None else float(first * dt)
    alarm_channels = [a["channel"] for a in s["alarms"] if a["first_sample"] == first]
    truth = b[PLANT_TRUTH.absolute]
    true_bias = {o: 0.0 for o in sys_.outputs}
    true_bias.update(true_biases(truth_facts(truth, sys_)))
    return {
        "scenario": scenario.name,
        "gains": str(gains),
        "fault": fault,
        "detected_at": detected_at,
        "detection_delay": (None if detected_at is None or fault is None
                            else round(detected_at - fault["time"], 6)),
        "alarm_channels": alarm_channels,
        "isolated": s["isolated"],
        "bias_estimate": s["bias_estimate"],
        "true_bias": true_bias,
        "transitions": mode_tracking(truth.column("mode").astype(int), out.mode, dt),
        "samples": counts,
        "lost": int(sum(K - c for c in counts.values())),
    }


def _print(s: dict[str, Any]) -> None:
    f = s["fault"] or {}
    out = f.get("output")
    rows = [
        ("scenario", s["scenario"]),
        ("fault", f"{f.get('channel')} +{f.get('magnitude', 0):g} at {f.get('time', 0):g} s"
         if f else "none"),
        ("detected at", "not detected" if s["detected_at"] is None else
         f"{s['detected_at']:g} s (delay {s['detection_delay']:g} s, alarm on "
         f"{', '.join(s['alarm_channels'])})"),
        ("isolated sensor", ", ".join(s["isolated"]) or "none"),
        ("sigma-hat", ", ".join(f"{o} {v:+.5f}" for o, v in s["bias_estimate"].items())),
        ("true bias", ", ".join(f"{o} {v:+.5f}" for o, v in s["true_bias"].items())),
    ]
    if out:
        err = s["bias_estimate"][out] - s["true_bias"][out]
        rows.append((f"error on {out}", f"{err:+.5f} ({abs(err) / max(f['magnitude'], 1e-12):.1%}"
                                        f" of the bias)"))
    t = s["transitions"]
    rows += [
        ("mode transitions", f"{t['tracked']}/{t['true']} tracked (within "
                             f"{t['max_delay_s'] or 0:g} s), estimated mode = true mode at "
                             f"{t['mode_agreement']:.1%} of samples"),
        ("samples", f"{min(s['samples'].values())} per topic on {len(s['samples'])} topics, "
                    f"{s['lost']} lost"),
        ("wall time", f"{s['wall_time_s']:g} s"),
        ("bag", str(Path(s["output"]) / "bag")),
        ("report", s.get("report") or "none (see the warning above)"),
    ]
    print_table(rows, title="fd_monitor demo: sensor-bias diagnosis on three_tank "
                            "(5 processes over DDS)")
