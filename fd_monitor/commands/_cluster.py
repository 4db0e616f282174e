"""The Dask options shared by ``analyze`` (many bags) and ``evaluate``, and ``evaluate``'s
campaign on Dask (:mod:`fd_monitor.analysis.evaluate_dask`)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from fd_monitor.analysis.evaluate import CampaignRow, run_campaign

__all__ = ["add_cluster_arguments", "campaign_rows", "wants_cluster"]


def add_cluster_arguments(parser: Any) -> None:
    """``--workers N`` and ``--scheduler tcp://HOST:PORT`` on a parser or argument group."""
    from fd_monitor.commands._common import count

    parser.add_argument("--workers", type=count(0, 1024), default=None, metavar="N",
                        help="worker processes of the embedded Dask cluster (default: one "
                             "per core; evaluate --workers 0: in this process, no cluster)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="run on this Dask scheduler's workers instead (they need the "
                             "fd_monitor package; for bags, the bags at the same paths)")


def wants_cluster(args: argparse.Namespace, tasks: int, runs: int, chunk: int) -> bool:
    """``evaluate`` runs on Dask when ``--workers N > 0`` or ``--scheduler`` is given, or when its
    campaign has more than one chunk of runs (a smaller one runs in this process: a
    cluster's few seconds of start-up would cost more than they save)."""
    if args.scheduler is not None:
        return True
    if args.workers is not None:
        return args.workers > 0
    return tasks > 1 and runs > chunk


def campaign_rows(args: argparse.Namespace, gains: Any, scenarios: Sequence[Any], runs: int,
                  **kw: Any) -> list[CampaignRow]:
    """:func:`~fd_monitor.analysis.evaluate.run_campaign` in this process, or its chunks on
    Dask (:func:`~fd_monitor.analysis.evaluate_dask.run_campaign_on`; same numbers). A
    campaign stopped with Ctrl-C returns the rows of the runs that finished (a note on
    stderr)."""
    import sys

    chunk = int(kw.get("chunk", 250))
    tasks = len(scenarios) * -(-runs // chunk)
    if not wants_cluster(args, tasks, runs, chunk):
        return run_campaign(gains, scenarios, runs, **kw)
    from fd_monitor.analysis.evaluate_dask import run_campaign_on
    from fd_monitor.analysis.scaleout import open_client

    with open_client(args.workers, args.scheduler) as client:
        rows, done = run_campaign_on(client, gains, scenarios, runs, **kw)
    if done.stopped:
        print(f"evaluate: STOPPED by Ctrl-C after {done.done} of {done.total} chunks: the "
              f"rows count the runs that finished", file=sys.stderr)
    return rows
