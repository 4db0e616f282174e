"""Throughput and latency of the distributed diagnosis chain, and of raw rclpy, on this machine.

Two measurements in one run, both over DDS on loopback (isolated ROS_DOMAIN_ID):

1. **raw rclpy**: a publisher process sends stamped Float64MultiArray messages (3 values, like
   /plant/y) at each rate to a subscriber in this process (reliable QoS of fd_monitor).
2. **pipeline**: observer, detector, agei and bias_estimator run as four processes; this
   process is the plant driver: it publishes /plant/u and /plant/y at each rate (samples of
   the demo scenario, consecutive stamps across rates) and subscribes to /fd/alarm.
3. **monitor**: the same four nodes on one executor in one process (``monitor``), same driver.

For each rate: samples missing (not received within the drain window: 5 s + 10 ms per
sample; lossless QoS means these are late, not dropped, unless the run is cut), and latency
p50/p99 from publishing y_k to receiving alarm_k (raw: to receiving message k) — the time
through observer -> detector plus one hop back to this process. A rate is *sustained* when
nothing is missing and the backlog at the end of the burst drains within 0.5 s (the chain kept
up instead of queueing).

Run: ``.venv/bin/python benchmarks/bench_pipeline.py [--rates 100 250 500 1000 2000]
[--seconds 3] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

RAW_PUBLISHER = r"""
import sys, time, rclpy
from fd_monitor.nodes.common import data_pub_qos, use_dds_profile
from fd_monitor.nodes.conversions import to_msg
use_dds_profile(); rclpy.init()
node = rclpy.create_node("raw_pub")
pub = node.create_publisher(__import__("std_msgs.msg").msg.Float64MultiArray, "/bench/raw",
                            data_pub_qos())
rates = [float(r) for r in sys.argv[1].split(",")]; seconds = float(sys.argv[2])
while pub.get_subscription_count() < 1:
    rclpy.spin_once(node, timeout_sec=0.01)
k = 0
for rate in rates:
    n = int(rate * seconds); t0 = time.perf_counter()
    for i in range(n):
        due = t0 + i / rate
        while time.perf_counter() < due:
            pass
        pub.publish(to_msg(("t", "a", "b"), k, [time.perf_counter(), 0.0, 0.0])); k += 1
    time.sleep(5.5)  # drain window of the subscriber (the measurement's, not a synchroniser)
try:
    pub.wait_for_all_acked()
except Exception:
    pass  # terminated by the benchmark while waiting: nothing left to measure
"""


def env() -> dict[str, str]:
    from fd_monitor.nodes.common import use_dds_profile

    use_dds_profile()
    e = dict(os.environ)
    e.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
    e["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    e.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    e.setdefault("ROS_LOG_DIR", "/tmp/fd_monitor_bench_logs")
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    os.environ.update({k: e[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                                         "RMW_IMPLEMENTATION", "ROS_LOG_DIR")})
    return e


class Receiver:
    """Spin a subscriber in a thread; record the arrival time of each stamp."""

    def __init__(self, topic: str, send_time_in_data: bool = False) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import Float64MultiArray

        from fd_monitor.nodes.common import data_sub_qos

        self.node = rclpy.create_node(f"bench_rx_{topic.strip('/').replace('/', '_')}")
        self.arrivals: dict[int, float] = {}
        #: Send times carried in data[1] by the raw publisher (same machine clock).
        self.sent: dict[int, float] = {}
        self.send_time_in_data = send_time_in_data
        self.node.create_subscription(Float64MultiArray, topic, self._cb, data_sub_qos())
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _cb(self, msg) -> None:
        k = int(msg.data[0])
        self.arrivals[k] = time.perf_counter()
        if self.send_time_in_data:
            self.sent[k] = float(msg.data[1])

    def _spin(self) -> None:
        while not self._stop:
            self.ex.spin_once(timeout_sec=0.05)

    def wait_for(self, stamps: range, timeout: float) -> float:
        """Wait until every stamp arrived or timeout; return when the last one arrived."""
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            if all(k in self.arrivals for k in stamps):
                break
            time.sleep(0.01)  # polling a dict filled by the spinning thread
        got = [self.arrivals[k] for k in stamps if k in self.arrivals]
        return max(got) if got else float("nan")

    def close(self) -> None:
        self._stop = True
        self.thread.join(2)
        self.ex.shutdown()
        self.node.destroy_node()


def stats(name: str, rate: float, stamps: range, sent: dict[int, float], rx: Receiver,
          burst_end: float, last: float) -> dict:
    lat = np.array([rx.arrivals[k] - sent[k] for k in stamps if k in rx.arrivals]) * 1e3
    lost = len(stamps) - lat.size
    drain = last - burst_end if np.isfinite(last) else float("inf")
    return {"what": name, "rate_hz": rate, "samples": len(stamps), "missing": lost,
            "p50_ms": float(np.percentile(lat, 50)) if lat.size else None,
            "p99_ms": float(np.percentile(lat, 99)) if lat.size else None,
            "drain_s": round(drain, 3), "sustained": lost == 0 and drain < 0.5}


def bench_raw(rates: list[float], seconds: float, e: dict[str, str]) -> list[dict]:
    rx = Receiver("/bench/raw", send_time_in_data=True)
    sent = rx.sent
    p = subprocess.Popen([sys.executable, "-c", RAW_PUBLISHER, ",".join(map(str, rates)),
                          str(seconds)], env=e)
    out, k = [], 0
    try:
        for rate in rates:
            n = int(rate * seconds)
            stamps = range(k, k + n)
            rx.wait_for(range(k, k + 1), 30.0)
            t_first = rx.arrivals.get(k, time.perf_counter())
            last = rx.wait_for(stamps, seconds + 5.0)
            out.append(stats("raw rclpy (2 processes)", rate, stamps, sent, rx,
                             t_first + seconds, last))
            k += n
    finally:
        p.terminate()
        p.wait(10)
        rx.close()
    return out


LAYOUTS = {
    "pipeline (4 node processes)": ("observer", "detector", "agei", "bias_estimator"),
    "monitor (1 process, 4 nodes)": ("monitor",),
}


def bench_pipeline(rates: list[float], seconds: float, e: dict[str, str],
                   what: str = "pipeline (4 node processes)") -> list[dict]:
    import rclpy
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.core.simulator import simulate
    from fd_monitor.nodes.common import data_pub_qos
    from fd_monitor.nodes.conversions import to_msg
    from fd_monitor.scenario import load_scenario

    sc = load_scenario("three_tank_bias_h1")
    total = sum(int(r * seconds) for r in rates) + 20
    traj = simulate(sc, None, total)
    u, y = traj.u[0], traj.y[0]
    procs = [subprocess.Popen([sys.executable, "-m", "fd_monitor", "run", n], env=e,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for n in LAYOUTS[what]]
    node = rclpy.create_node("bench_driver")
    pu = node.create_publisher(Float64MultiArray, "/plant/u", data_pub_qos())
    py = node.create_publisher(Float64MultiArray, "/plant/y", data_pub_qos())
    rx = Receiver("/fd/alarm")
    out = []
    try:
        deadline = time.monotonic() + 60
        need = 2  # observer and bias_estimator read /plant/u and /plant/y (in both layouts)
        while (py.get_subscription_count() < need or pu.get_subscription_count() < need
               or rx.node.count_publishers("/fd/alarm") < 1) and time.monotonic() < deadline:
            time.sleep(0.05)  # discovery of the four node processes
        labels_u, labels_y = sc.system.inputs, sc.system.outputs
        sent: dict[int, float] = {}
        # Warm-up: every link of the chain matched and the first samples through, before
        # anything is measured (discovery between the node processes takes a moment).
        warm = 20
        for i in range(warm):
            pu.publish(to_msg(labels_u, i, u[i]))
            py.publish(to_msg(labels_y, i, y[i]))
        rx.wait_for(range(warm), 60.0)
        k = warm
        for rate in rates:
            n = int(rate * seconds)
            t0 = time.perf_counter()
            for i in range(n):
                due = t0 + i / rate
                while time.perf_counter() < due:
                    pass
                pu.publish(to_msg(labels_u, k + i, u[k + i]))
                sent[k + i] = time.perf_counter()
                py.publish(to_msg(labels_y, k + i, y[k + i]))
            burst_end = time.perf_counter()
            stamps = range(k, k + n)
            last = rx.wait_for(stamps, 5.0 + n / 100.0)
            out.append(stats(what, rate, stamps, sent, rx, burst_end, last))
            k += n
            if out[-1]["missing"]:
                break  # the chain fell behind: later rates would only measure the backlog
    finally:
        rx.close()
        node.destroy_node()
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[100, 250, 500, 1000, 2000])
    ap.add_argument("--seconds", type=float, default=3.0, help="s per rate")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    e = env()
    import rclpy

    rclpy.init()
    try:
        rows = bench_raw(args.rates, args.seconds, e)
        for what in LAYOUTS:
            rows += bench_pipeline(args.rates, args.seconds, e, what)
    finally:
        rclpy.try_shutdown()
    best = {w: max([r["rate_hz"] for r in rows if r["what"] == w and r["sustained"]],
                   default=0.0) for w in {r["what"] for r in rows}}
    if args.json:
        json.dump({"rows": rows, "highest_sustained_hz": best}, sys.stdout, indent=2)
        print()
        return 0
    print(f"{'what':30} {'rate Hz':>8} {'samples':>8} {'miss':>5} {'p50 ms':>8} "
          f"{'p99 ms':>8} {'drain s':>8}  sustained")
    for r in rows:
        p50 = f"{r['p50_ms']:.2f}" if r["p50_ms"] is not None else "-"
        p99 = f"{r['p99_ms']:.2f}" if r["p99_ms"] is not None else "-"
        print(f"{r['what']:30} {r['rate_hz']:8g} {r['samples']:8d} {r['missing']:5d} {p50:>8} "
              f"{p99:>8} {r['drain_s']:8.3f}  {r['sustained']}")
    for w, v in sorted(best.items()):
        print(f"highest rate sustained without loss, {w}: {v:g} Hz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
