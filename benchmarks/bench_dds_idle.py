"""What DDS costs a robot's process when no data flows: discovery and idle writers.

N processes, each one rclpy node shaped like a robot's ``monitor`` (namespace
``/robot<i>``: ``--writers`` reliable publishers of fd_monitor's data QoS, the two data
subscriptions ``plant/u`` and ``plant/y``, rclpy's EventsExecutor in a ``spin_once`` loop as
``run_node``), nothing published. Once every process runs and discovery has settled
(``--settle`` s), the CPU the N processes use during ``--seconds`` s is measured (/proc) per
process and second; what remains is Fast DDS's own idle work, mostly discovery: every
participant announces itself (SPDP) every lease announcement period to every participant it
knows and, under ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, to the 32 loopback ports a
participant may have; each of these is received and checked by every other one.

Printed per DDS configuration (``--dds LABEL=SPEC`` as in ``bench_robots.py``; first the
nodes' profile) and N: CPU per process (ms per s; at 100 Hz, ms per s / 100 = ms per
sample), RSS and PSS per process (PSS: the shared libraries' pages divided among the
processes that map them, what N processes really take: N x PSS), and the first process's CPU
by thread name, with the load average.

Run: ``.venv/bin/python benchmarks/bench_dds_idle.py [--procs 1 8 32] [--writers 7]
[--seconds 20] [--settle 8] [--dds LABEL=SPEC ...]``. Isolated ROS_DOMAIN_ID, loopback
discovery.
"""

from __future__ import annotations

import argparse
import itertools
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_robots import (  # noqa: E402, I001
    cpu_seconds, dds_variants, env, load, pss_mb, rss_mb, thread_cpu)

#: ``python -c IDLE <index> <writers> <rate>``: a monitor-shaped node that publishes nothing
#: (rate 0) or, on a timer at ``rate`` Hz, one serialized 7-value message on every writer.
IDLE = r"""
import sys
i, w, rate = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray
from fd_monitor.nodes.qos import data_pub_qos, data_sub_qos, pub_events, sub_events
rclpy.init()
n = rclpy.create_node("idle", namespace=f"/robot{i}")
pubs = [n.create_publisher(Float64MultiArray, f"fd/out{j}", data_pub_qos(), **pub_events())
        for j in range(w)]
subs = [n.create_subscription(Float64MultiArray, t, lambda m: None, data_sub_qos(), raw=True,
                              **sub_events()) for t in ("plant/u", "plant/y")]
if rate > 0:
    msg = serialize_message(Float64MultiArray(data=[0.0] * 7))
    def tick():
        for p in pubs:
            p.publish(msg)
    n.create_timer(1.0 / rate, tick)
ex = EventsExecutor(); ex.add_node(n)
try:
    while rclpy.ok():
        ex.spin_once(timeout_sec=0.1)
except BaseException:
    pass
"""


#: ``python -c RX <processes> <writers>``: subscribes to every writer of every process (the
#: fd_monitor data QoS, serialized, not read), as a recorder of all outputs would.
RX = r"""
import sys
n, w = int(sys.argv[1]), int(sys.argv[2])
import rclpy
from rclpy.experimental import EventsExecutor
from std_msgs.msg import Float64MultiArray
from fd_monitor.nodes.qos import data_sub_qos, sub_events
rclpy.init()
node = rclpy.create_node("idle_rx")
subs = [node.create_subscription(Float64MultiArray, f"/robot{i}/fd/out{j}", lambda m: None,
                                 data_sub_qos(), raw=True, **sub_events())
        for i in range(n) for j in range(w)]
ex = EventsExecutor(); ex.add_node(node)
try:
    while rclpy.ok():
        ex.spin_once(timeout_sec=0.1)
except BaseException:
    pass
"""


def run(n: int, writers: int, seconds: float, settle: float, e: dict[str, str],
        rate: float = 0.0) -> dict:
    """N processes: start, settle, measure, stop. ``rate`` > 0: each publishes on every
    writer at ``rate`` Hz to a receiver process subscribed to all of them."""
    procs = [subprocess.Popen([sys.executable, "-c", IDLE, str(i), str(writers), str(rate)],
                              env=e, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for i in range(n)]
    if rate > 0:
        procs.append(subprocess.Popen([sys.executable, "-c", RX, str(n), str(writers)], env=e,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    try:
        time.sleep(settle)
        pids = [p.pid for p in procs[:n]]
        if any(p.poll() is not None for p in procs):
            raise RuntimeError("an idle process ended at start")
        cpu0, th0, t0 = cpu_seconds(pids), thread_cpu(pids[0]), time.perf_counter()
        time.sleep(seconds)
        cpu, wall = cpu_seconds(pids) - cpu0, time.perf_counter() - t0
        th = {k: v - th0.get(k, 0.0) for k, v in thread_cpu(pids[0]).items()}
        rss = [rss_mb(p) for p in pids]
        pss = [pss_mb(p) for p in pids]
        return {"n": n, "ms_per_s": cpu / n / wall * 1e3, "rss": sum(rss) / n,
                "pss": sum(pss) / n, "load": load(),
                "threads": {k: v / wall * 1e3 for k, v in
                            sorted(th.items(), key=lambda kv: -kv[1]) if v > 0}}
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procs", type=int, nargs="+", default=[1, 8, 32])
    ap.add_argument("--writers", type=int, default=7, help="publishers per process")
    ap.add_argument("--seconds", type=float, default=20.0, help="measured window, s")
    ap.add_argument("--settle", type=float, default=8.0, help="s after start, not measured")
    ap.add_argument("--rate", type=float, nargs="+", default=[0.0],
                    help="Hz each writer publishes at, to a receiver of every writer (0: "
                         "idle); one row per value")
    ap.add_argument("--dds", action="append", default=[], metavar="LABEL=SPEC",
                    help="another DDS configuration (as bench_robots.py --dds)")
    args = ap.parse_args()
    e = env()
    print(f"load average {load():.2f} (1 min, {os.cpu_count()} cores); idle processes, "
          f"{args.writers} writers each; {args.seconds:g} s measured after {args.settle:g} s")
    for n, rate in itertools.product(args.procs, args.rate):
        for label, me in dds_variants(args.dds, e):
            r = run(n, args.writers, args.seconds, args.settle, me, rate)
            top = ", ".join(f"{k} {v:.2f}" for k, v in list(r["threads"].items())[:4])
            dds = sum(v for k, v in r["threads"].items() if k.startswith("dds."))
            print(f"{n:3d} processes, {rate:g} Hz [{label}]{'':{max(0, 12 - len(label))}} "
                  f"{r['ms_per_s']:6.2f} ms/s per process  RSS {r['rss']:5.1f} MB  "
                  f"PSS {r['pss']:5.1f} MB  load {r['load']:.2f}\n"
                  f"{'':20} first process, ms/s: dds.* threads {dds:.2f}; by thread: "
                  f"{top}", flush=True)
    print(f"load average {load():.2f} after")
    return 0


if __name__ == "__main__":
    sys.exit(main())
