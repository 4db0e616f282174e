"""Replay throughput into the live monitor (no lost sample) against raw rclpy, one run.

Run: .venv/bin/python benchmarks/bench_replay.py [--bag bags/three_tank_bias_h1] [--runs 7]
     [--analyze-only]

1. **Live monitor**: ``python -m fd_monitor run monitor`` (the fused node: one join, one
   ``Monitor.step`` per sample) and ``record /fd/alarm`` are started, then
   ``replay --rate 0`` publishes the bag's ``/plant/u`` and ``/plant/y`` flat out (reliable,
   acknowledgement-paced, lossless). The rate is (N - 1) / (receive time of the last
   /fd/alarm - of the first), from the recorder's
   timestamps; every stamp 0..N-1 must be there (no lost sample).
2. **Raw rclpy**: this script publishes the same CDR bytes (``/plant/u`` and ``/plant/y`` of
   the bag, 2 N messages) as fast as ``publish()`` returns, reliable QoS with a history that
   holds them all, to a second process that only counts them; its rate is (N - 1) / (last
   arrival - first arrival) in samples (u, y pairs) per second, every message received.

Both use the same DDS (Fast DDS, loopback, the project's config/fastdds.xml) and run in one
invocation, so the ratio compares like with like on this machine.

3. **analyze wall time** (first, before any ROS process runs; ``--analyze-only`` stops there):
   ``python -m fd_monitor analyze BAG --gains three_tank_thresholds`` as a user types it in a
   shell, a fresh interpreter per run (start, imports, reading, run, printing), median of
   ``--runs`` runs after a warm-up (target < 0.5 s), with the load average. With the Python
   bytecode cached, as an installed package has it (a private ``PYTHONPYCACHEPREFIX``), and,
   when the shell sets ``PYTHONDONTWRITEBYTECODE=1`` (this development machine does), as it
   runs there: fd_monitor's own modules compiled from source at every run. ``python -c
   pass`` in the same environment is the part no fd_monitor code can change (the ros-jazzy
   wheels' ``.pth`` starts the interpreter twice).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _env() -> dict[str, str]:
    sys.path.insert(0, str(REPO))
    from fd_monitor.nodes.pacing import use_dds_profile

    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="fd_bench_roslog_"))
    use_dds_profile()
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _fd(args: list[str], env: dict[str, str], out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fd_monitor", *args], cwd=REPO, env=env,
                            stdout=out.open("w"), stderr=subprocess.STDOUT)


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


def live_monitor(bag: Path, env: dict[str, str], tmp: Path) -> dict[str, float]:
    """Replay into the monitor process; samples/s from the recorder's receive stamps."""
    import numpy as np

    from fd_monitor.wire.bag_reader import read_bag
    from fd_monitor.wire.topics import ALARM, PLANT_U, PLANT_Y

    t_u, t_y, t_alarm = PLANT_U.absolute, PLANT_Y.absolute, ALARM.absolute
    n = len(read_bag(bag, [t_y])[t_y])
    mon = _fd(["run", "monitor"], env, tmp / "monitor.log")
    rec = _fd(["record", t_alarm, "-o", str(tmp / "rec"), "--until", f"{t_alarm}={n}"],
              env, tmp / "record.log")
    try:
        t0 = time.perf_counter()
        # replay waits only for the monitor's subscriptions: without this the recorder
        # could still be matching /fd/alarm when the first alarms go out, miss hundreds of
        # them and wait for them until its timeout (seen in 4 of 5 runs at load 1-4)
        subprocess.run([sys.executable, __file__, "--wait-graph", t_alarm], cwd=REPO, env=env,
                       check=True, timeout=120)
        rep = subprocess.run([sys.executable, "-m", "fd_monitor", "replay", str(bag),
                              "--topics", t_u, t_y, "--rate", "0",
                              "--wait-subscribers", "1"], cwd=REPO, env=env,
                             capture_output=True, text=True, timeout=600)
        if rep.returncode != 0:
            raise SystemExit(f"replay failed: {rep.stderr}")
        rec.wait(600)
        wall = time.perf_counter() - t0
    finally:
        _stop(rec)
        _stop(mon)
    a = read_bag(tmp / "rec", [t_alarm])[t_alarm]
    lost = n - len(np.unique(a.stamps))
    span = (a.receive_ns[-1] - a.receive_ns[0]) / 1e9
    return {"samples": n, "lost": lost, "rate": (len(a) - 1) / span, "wall_s": wall}


def raw_subscriber(n_msgs: int) -> None:
    """Child process: count n_msgs raw messages on /bench/u and /bench/y, print timing."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray

    rclpy.init()
    node = Node("bench_raw_sub")
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    times: list[float] = []
    for t in ("/bench/u", "/bench/y"):
        node.create_subscription(Float64MultiArray, t, lambda m: times.append(time.monotonic()),
                                 qos, raw=True)
    print("ready", flush=True)
    deadline = time.monotonic() + 600
    while len(times) < n_msgs and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps({"received": len(times), "first": times[0] if times else 0.0,
                      "last": times[-1] if times else 0.0}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def wait_graph(topic: str) -> None:
    """Child process: return once ``topic`` has a publisher and a subscriber in the graph
    (both endpoints announced; exit status 1 after 60 s)."""
    import rclpy
    from rclpy.node import Node

    rclpy.init()
    node = Node("bench_wait_graph")
    deadline = time.monotonic() + 60
    try:
        while node.count_publishers(topic) < 1 or node.count_subscribers(topic) < 1:
            if time.monotonic() > deadline:
                raise SystemExit(f"{topic}: no publisher and subscriber after 60 s")
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def raw_rclpy(bag: Path, env: dict[str, str]) -> dict[str, float]:
    """Publish the bag's u, y CDR bytes flat out to a counting process."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.wire.bag_scanner import read_raw
    from fd_monitor.wire.topics import PLANT_U, PLANT_Y

    plant = (PLANT_U.absolute, PLANT_Y.absolute)
    msgs = [(t, raw) for t, _m, _ts, raw in read_raw(bag, list(plant))]
    n_msgs = len(msgs)
    sub = subprocess.Popen([sys.executable, __file__, "--raw-sub", str(n_msgs)], cwd=REPO,
                           env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout is not None
        if sub.stdout.readline().strip() != "ready":
            raise SystemExit("raw subscriber did not start")
        rclpy.init()
        node = Node("bench_raw_pub")
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=n_msgs + 10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        pubs = {t: node.create_publisher(Float64MultiArray, t.replace("/plant", "/bench"), qos)
                for t in plant}
        deadline = time.monotonic() + 60
        while any(p.get_subscription_count() < 1 for p in pubs.values()):
            if time.monotonic() > deadline:
                raise SystemExit("raw subscriber not matched")
            rclpy.spin_once(node, timeout_sec=0.05)
        for t, raw in msgs:
            pubs[t].publish(raw)
        for p in pubs.values():
            p.wait_for_all_acked(rclpy.duration.Duration(seconds=120))
        out, _ = sub.communicate(timeout=600)
        node.destroy_node()
        rclpy.try_shutdown()
    finally:
        _stop(sub)
    doc = json.loads(out.strip().splitlines()[-1])
    n = n_msgs // 2
    span = doc["last"] - doc["first"]
    return {"samples": n, "lost": n_msgs - doc["received"],
            "rate": (doc["received"] / 2 - 1) / span}


def _walls(cmd: list[str], env: dict[str, str], runs: int) -> list[float]:
    """Wall times of ``cmd`` (a new process each run) after one warm-up run, s."""
    subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, check=True, timeout=120)
    walls = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, check=True, timeout=120)
        walls.append(time.perf_counter() - t0)
    return walls


def analyze_wall(bag: Path, gains: str, env: dict[str, str], runs: int
                 ) -> dict[str, list[float]]:
    """Wall time of ``analyze BAG --gains GAINS`` as typed in a shell, s, and of an empty
    interpreter start (``python -c pass``) in the same environment."""
    # As from a fresh shell: the ros-jazzy wheels' .pth re-executes the interpreter once to
    # set LD_LIBRARY_PATH unless this marker (inherited from this bootstrapped script) is set.
    shell = {k: v for k, v in env.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    analyze = [sys.executable, "-m", "fd_monitor", "analyze", str(bag), "--gains", gains]
    out: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as cache:
        cached = {k: v for k, v in shell.items() if k != "PYTHONDONTWRITEBYTECODE"}
        cached["PYTHONPYCACHEPREFIX"] = cache
        out["analyze, bytecode cached (as installed)"] = _walls(analyze, cached, runs)
        if "PYTHONDONTWRITEBYTECODE" in shell:
            out["analyze, PYTHONDONTWRITEBYTECODE=1 (this shell)"] = _walls(analyze, shell,
                                                                              runs)
        out["python -c pass (interpreter start + re-exec)"] = _walls(
            [sys.executable, "-c", "pass"], cached, runs)
    return out


def _load() -> str:
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default=str(REPO / "bags" / "three_tank_bias_h1"))
    ap.add_argument("--raw-sub", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--wait-graph", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--gains", default="three_tank_thresholds",
                    help="gain file of the analyze timing")
    ap.add_argument("--runs", type=int, default=7, help="analyze runs (median printed)")
    ap.add_argument("--analyze-only", action="store_true",
                    help="only the analyze wall time (no ROS)")
    args = ap.parse_args()
    if args.raw_sub is not None:
        raw_subscriber(args.raw_sub)
        return
    if args.wait_graph is not None:
        wait_graph(args.wait_graph)
        return
    env = _env()
    bag = Path(args.bag)
    before = _load()
    walls = analyze_wall(bag, args.gains, env, args.runs)
    print(f"analyze {bag} --gains {args.gains}: wall time, median of {args.runs} runs "
          f"(min-max), target < 0.5 s")
    for name, w in walls.items():
        print(f"  {name:<50} {statistics.median(w):.3f} s ({min(w):.3f}-{max(w):.3f})")
    print(f"  {before} before, {_load()} after")
    if args.analyze_only:
        return
    with tempfile.TemporaryDirectory() as d:
        live = live_monitor(bag, env, Path(d))
    raw = raw_rclpy(bag, env)
    print(f"bag {bag} ({live['samples']} samples of u and y)")
    print(f"{'path':<46} {'samples/s':>10} {'lost':>5}")
    print(f"{'replay -> monitor (fused) -> /fd/alarm':<46} {live['rate']:>10.0f} "
          f"{live['lost']:>5}")
    print(f"{'raw rclpy publish(bytes) -> subscriber':<46} {raw['rate']:>10.0f} "
          f"{raw['lost']:>5}")
    print(f"ratio live / raw: {live['rate'] / raw['rate']:.3f}  (live wall time incl. start "
          f"and discovery: {live['wall_s']:.1f} s)")


if __name__ == "__main__":
    main()
