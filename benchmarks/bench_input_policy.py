"""Cost of the one input policy per message (pure, no ROS).

Run: .venv/bin/python benchmarks/bench_input_policy.py [--messages 200000] [--repeat 6]

In-order ``u``/``y`` messages pushed through :class:`fd_monitor.wire.stream.InputStream`
(order check, :class:`~fd_monitor.wire.join.StampJoin`, release) -- what a node's callback
and offline reading run per message -- beside the same three calls made inline (order check,
``join.put``, ``join.ready``), as the nodes' callback made them before. Best of ``--repeat``.
"""

from __future__ import annotations

import argparse
import time

from fd_monitor.wire.join import StampJoin
from fd_monitor.wire.stream import GAP_TIMEOUT, STAMP_HORIZON, InputStream, TopicOrder


def _join() -> StampJoin:
    return StampJoin(["u", "y"], gap_timeout=GAP_TIMEOUT, horizon=STAMP_HORIZON)


def inline(n: int) -> float:
    join, orders = _join(), {x: TopicOrder(x) for x in "uy"}
    t0 = time.perf_counter()
    for k in range(n // 2):
        now = k * 0.001
        for name in ("u", "y"):
            _line, duplicate = orders[name].check(k)
            if duplicate:
                continue
            if join.put(name, k, 1.0, now) is None:
                for _s in join.ready(now):
                    pass
    return time.perf_counter() - t0


def policy(n: int) -> float:
    orders = {x: TopicOrder(x) for x in "uy"}
    stream = InputStream(_join(), lambda s: True, lambda kind, line, stamp: None)
    t0 = time.perf_counter()
    for k in range(n // 2):
        now = k * 0.001
        for name in ("u", "y"):
            stream.stamped(orders[name], name, k, 1.0, now)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=6)
    args = ap.parse_args()
    n = args.messages
    for name, f in (("inline calls", inline), ("InputStream", policy)):
        best = min(f(n) for _ in range(args.repeat))
        print(f"{name:<14} {best / n * 1e6:6.2f} us per message ({n} messages, best of "
              f"{args.repeat})")


if __name__ == "__main__":
    main()
