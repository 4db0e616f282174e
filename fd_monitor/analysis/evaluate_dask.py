"""Monte Carlo campaigns across Dask workers: chunks of runs as tasks, same numbers anywhere.

:func:`run_campaign_on` cuts a campaign into the chunks :func:`fd_monitor.analysis.evaluate.
run_campaign` simulates one after the other (``chunk`` runs of one scenario, seeds
``seed0 + i``), runs each chunk as one task (:func:`campaign_task`) on a Dask client
(:func:`fd_monitor.analysis.scaleout.open_client`: an embedded LocalCluster or a real
cluster) and reduces the results in chunk order. A run's numbers depend only on its seed and
the chunks are the same whatever the number of workers, so the metrics are identical to the
in-process campaign's, with 1 worker or 100.

Ctrl-C stops the campaign and keeps the chunks that finished: the rows then count only the
runs that finished (``runs``), and ``stopped`` says so.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, TextIO

import numpy as np

from fd_monitor.analysis.evaluate import (
    CampaignRow,
    _row,
    chunk_alarms,
    get_runner,
    monitored_plant,
)
from fd_monitor.analysis.scaleout import RateBar, TaskRun, run_tasks
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.scenario import Scenario
from fd_monitor.model.system import System

__all__ = ["campaign_task", "run_campaign_on"]


def campaign_task(job: Mapping[str, Any]) -> dict[tuple[str, int], Any]:
    """One chunk of runs (a Dask task): :func:`~fd_monitor.analysis.evaluate.chunk_alarms`.

    Parameters
    ----------
    job : mapping
        ``gains``, ``scenario``, ``seeds``, ``variants``, ``rhos``, ``transient``,
        ``channels``, ``monitor`` (the gain file's plant).
    """
    gains = job["gains"]
    return chunk_alarms(get_runner(gains.method), gains, job["scenario"], job["seeds"],
                        job["variants"], job["rhos"], job["transient"], job["channels"],
                        job["monitor"])


def run_campaign_on(client: Any, gains: GainFile, scenarios: Sequence[Scenario], runs: int,
                    *, seed0: int = 0, chunk: int = 250, rhos: Sequence[float] | None = None,
                    transient: float = 0.0, channels: Sequence[str] | None = None,
                    variants: Mapping[str, Mapping[str, Any]] | None = None,
                    progress: bool = True, stream: TextIO | None = None,
                    system: System | None = None) -> tuple[list[CampaignRow], TaskRun]:
    """:func:`fd_monitor.analysis.evaluate.run_campaign` with its chunks as Dask tasks.

    Parameters
    ----------
    client : distributed.Client
    (others)
        As :func:`~fd_monitor.analysis.evaluate.run_campaign`.

    Returns
    -------
    (list of CampaignRow, TaskRun)
        The rows (in the in-process campaign's order) and what the run did (``stopped``
        after Ctrl-C: the rows count the finished runs only).
    """
    if runs < 1:
        raise FdMonitorError(f"--runs: expected >= 1, got {runs}")
    get_runner(gains.method)                 # an unknown method: one line, before any task
    variants = {k: dict(v) for k, v in (variants or {gains.method: {}}).items()}
    rho_list: list[float | None] = list(rhos) if rhos else [None]
    monitors = {sc.name: monitored_plant(gains, sc, system) for sc in scenarios}
    jobs: list[dict[str, Any]] = []
    where: list[tuple[int, int]] = []        # (scenario index, chunk index) of each job
    for s, sc in enumerate(scenarios):
        for c in range(-(-runs // chunk)):
            seeds = list(range(seed0 + c * chunk, seed0 + min((c + 1) * chunk, runs)))
            jobs.append({"gains": gains, "scenario": sc, "seeds": seeds,
                         "variants": variants, "rhos": list(rhos) if rhos else None,
                         "transient": transient,
                         "channels": list(channels) if channels else None,
                         "monitor": monitors[sc.name]})
            where.append((s, c))
    job_of = {w: i for i, w in enumerate(where)}
    results: dict[tuple[int, int], Any] = {}
    weights = [len(j["seeds"]) for j in jobs]
    bar = RateBar(sum(weights), "evaluate", "runs", stream, progress)
    done = run_tasks(client, campaign_task, jobs,
                     lambda i, r: results.__setitem__(where[i], r), bar, weights)
    rows: list[CampaignRow] = []
    for s, sc in enumerate(scenarios):
        chunks = sorted(c for (si, c) in results if si == s)
        if not chunks:
            continue
        n = sum(weights[job_of[(s, c)]] for c in chunks)
        for label in variants:
            for j, rho in enumerate(rho_list):
                got = [results[(s, c)][(label, j)] for c in chunks]
                fa = [g[0] for g in got]
                first = None if got[0][1] is None else [np.asarray(g[1]) for g in got]
                rows.append(_row(sc, label, rho, n, fa, first))
    return rows, done
