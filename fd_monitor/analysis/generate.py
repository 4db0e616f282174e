"""Simulated bags: a scenario's messages, the library's corruptions, the MCAP file.

:func:`simulated_messages` is what ``python -m fd_monitor simulate`` records and what every
bag of the library (:mod:`fd_monitor.analysis.library`) starts from; :func:`bag_messages`
applies a bag spec's corruptions (module docstring of :mod:`fd_monitor.analysis.library`);
:func:`generate_bag` and :func:`generate_library` write them
(:func:`fd_monitor.wire.bag_writer.write_messages`), the same spec giving the same bytes.

Nothing here imports rclpy.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.library import BagSpec, Corruption, Library, LibraryError
from fd_monitor.core.simulator import (
    PlantSimulator,
    Trajectory,
    measured_signals,
    simulate,
    truth_values,
)
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.yaml_io import require_memory
from fd_monitor.wire.adapters import write_adapted
from fd_monitor.wire.bag_writer import BagWriter, write_messages
from fd_monitor.wire.topics import PLANT_TRUTH, PLANT_U, PLANT_Y, side_topic

__all__ = ["BYTES_PER_BAG_SAMPLE", "bag_messages", "check_bag_size", "generate_bag",
           "generate_library", "simulate_bag", "simulated_messages"]


@dataclass
class _Msg:
    """One simulated message (mutable: corruptions change it in place)."""

    t_ns: int
    topic: str
    stamp: int
    labels: tuple[str, ...]
    values: np.ndarray


def simulated_messages(scenario: Any, seed: int | None, n_samples: int) -> list[_Msg]:
    """Simulate a scenario and return its messages in recording order: per sample k
    (bag timestamp ``k Ts`` in ns) ``/plant/u``, ``/plant/y``, the measured side signals
    (:func:`~fd_monitor.core.simulator.measured_signals`) and ``/plant/truth``.

    Parameters
    ----------
    scenario : Scenario
    seed : int or None
        None: the scenario's.
    n_samples : int
    """

    sys_ = scenario.system
    dt = sys_.sample_time
    traj = simulate(scenario, seed, n_samples)
    topics = {PLANT_U.absolute: (PLANT_U.labels(sys_), traj.u[0]),
              PLANT_Y.absolute: (PLANT_Y.labels(sys_), traj.y[0]),
              **{side_topic(n).absolute: lv for n, lv in measured_signals(traj).items()},
              PLANT_TRUTH.absolute: (PLANT_TRUTH.labels(scenario), truth_values(traj))}
    return [_Msg(round(k * dt * 1e9), topic, int(k), labels, vals[k].copy())
            for k in range(n_samples) for topic, (labels, vals) in topics.items()]


#: Memory per simulated sample while a bag is built: its four messages as Python objects
#: (values, labels) and their CDR bytes, measured ~2 kB on three_tank; with margin.
BYTES_PER_BAG_SAMPLE = 4000.0


def check_bag_size(system: Any, duration: float, what: str, error: type[Exception]) -> int:
    """Samples of a simulated bag of ``duration`` s; refuse, before simulating, one whose
    messages would not fit in memory (:func:`~fd_monitor.model.yaml_io.require_memory`)."""
    n = duration / system.sample_time
    require_memory(BYTES_PER_BAG_SAMPLE * n, f"{what} {duration:g} s at "
                   f"{system.sample_time:g} s per sample ({n:.3g} samples)", error)
    return round(n)


def bag_messages(spec: BagSpec) -> tuple[list[_Msg], Any]:
    """Simulate ``spec`` and return its messages in recording order, corruptions applied.

    Returns
    -------
    (list, Scenario)
        Messages (:func:`simulated_messages`), and the scenario.
    """

    sc = load_scenario(spec.scenario)
    check_bag_size(sc.system, spec.duration, f"bag {spec.name}: duration", LibraryError)
    K = max(1, round(spec.duration / sc.system.sample_time))
    msgs = simulated_messages(sc, spec.seed, K)
    for c in spec.corruptions:
        msgs = _corrupt(msgs, c, spec)
    return msgs, sc


def _find(msgs: list[_Msg], topic: str, k: int, spec: BagSpec) -> int:
    for i, m in enumerate(msgs):
        if m.topic == topic and m.stamp == k:
            return i
    raise LibraryError(f"bag {spec.name}: corruption on {topic} stamp {k}: no such message")


def _corrupt(msgs: list[_Msg], c: Corruption, spec: BagSpec) -> list[_Msg]:
    if c.kind == "gap":
        k0, n = c.samples
        return [m for m in msgs if not k0 <= m.stamp < k0 + n]
    for k in c.samples:
        i = _find(msgs, c.topic, k, spec)
        m = msgs[i]
        if c.kind == "nan":
            if c.channel not in m.labels:
                raise LibraryError(f"bag {spec.name}: nan corruption: no channel "
                                   f"{c.channel!r} on {c.topic}")
            m.values[m.labels.index(str(c.channel))] = math.nan
        elif c.kind == "wrong_length":
            m.values, m.labels = m.values[:-1], m.labels[:-1]
        elif c.kind == "duplicate":
            msgs.insert(i + 1, _Msg(m.t_ns, m.topic, m.stamp, m.labels, m.values.copy()))
        else:  # out_of_order: stamp k + 1 recorded (and replayed) before stamp k
            j = _find(msgs, c.topic, k + 1, spec)
            a, b = msgs[i], msgs[j]
            a.stamp, b.stamp = b.stamp, a.stamp
            a.values, b.values = b.values, a.values
            a.labels, b.labels = b.labels, a.labels
    return msgs


def _write(path: str | Path, msgs: Sequence[_Msg]) -> Path:
    """Write messages into a new bag (:func:`fd_monitor.wire.bag_writer.write_messages`)."""
    return write_messages(path, ((m.topic, m.t_ns, m.stamp, m.labels, m.values)
                                 for m in msgs))


def simulate_bag(path: str | Path, scenario: Any, seed: int | None, n_samples: int,
                 adapter: Any = None) -> tuple[Path, tuple[str, ...]]:
    """Write the bag of :func:`simulated_messages` (``python -m fd_monitor simulate``); the
    bag of a library spec without corruptions, byte for byte.

    With ``adapter`` (a :class:`~fd_monitor.wire.adapters.Adapter` bound to the plant) u and
    y go into the bag as the robot's messages on the adapter's topics (header stamps t_k),
    written first; the side signals and the truth follow as simulated.

    Returns
    -------
    (pathlib.Path, tuple of str)
        The bag folder and its topics, in recording order.
    """
    if adapter is None:
        return _simulate_streaming(path, scenario, seed, n_samples)
    msgs = simulated_messages(scenario, seed, n_samples)

    t_u, t_y = PLANT_U.absolute, PLANT_Y.absolute
    ys = [m for m in msgs if m.topic == t_y]
    u = np.array([m.values for m in msgs if m.topic == t_u])
    rest = [m for m in msgs if m.topic not in (t_u, t_y)]
    with BagWriter(path) as w:
        write_adapted(w, adapter, [m.stamp for m in ys], u, np.array([m.values for m in ys]),
                      [m.t_ns for m in ys])
        for m in rest:
            w.write_array(m.topic, m.stamp, m.labels, m.values, m.t_ns)
    return Path(path), (*adapter.topics, *dict.fromkeys(m.topic for m in rest))


#: Samples simulated and written at a time by :func:`simulate_bag` (memory vs overhead).
SIM_CHUNK = 4096


def _simulate_streaming(path: str | Path, scenario: Any, seed: int | None, n_samples: int,
                        chunk: int = SIM_CHUNK) -> tuple[Path, tuple[str, ...]]:
    """:func:`simulate_bag` without an adapter, ``chunk`` samples at a time: the simulator is
    stepped, the chunk's messages written, and nothing of it kept, so memory does not grow
    with the bag's length. The bytes are :func:`simulated_messages` written by
    :func:`~fd_monitor.wire.bag_writer.write_messages` (the simulator is step-based and its noise
    drawn per run in fixed blocks: a chunk is the same samples, ``test/test_streaming.py``)."""
    sys_ = scenario.system
    dt = sys_.sample_time
    sim = PlantSimulator(scenario, [scenario.seed if seed is None else seed])
    topics: tuple[str, ...] = ()
    with BagWriter(path) as w:
        for k0 in range(0, n_samples, chunk):
            steps = [sim.step() for _ in range(min(chunk, n_samples - k0))]
            ks = np.arange(k0, k0 + len(steps))
            traj = Trajectory(scenario, sim.seeds, ks, ks * dt,
                              *(np.stack([getattr(st, f) for st in steps], axis=1)
                                for f in ("u", "y", "x", "mode", "faults", "rho")))
            cols = {PLANT_U.absolute: (PLANT_U.labels(sys_), traj.u[0]),
                    PLANT_Y.absolute: (PLANT_Y.labels(sys_), traj.y[0]),
                    **{side_topic(n).absolute: lv for n, lv in measured_signals(traj).items()},
                    PLANT_TRUTH.absolute: (PLANT_TRUTH.labels(scenario), truth_values(traj))}
            if not topics:
                topics = tuple(cols)
                for topic in topics:
                    w.add_topic(topic)
            for j, k in enumerate(ks.tolist()):
                for topic, (labels, vals) in cols.items():
                    w.write_array(topic, k, labels, vals[j], round(k * dt * 1e9))
    return Path(path), topics


def generate_bag(spec: BagSpec, folder: str | Path | None = None) -> Path:
    """(Re)write the bag of ``spec`` into ``folder`` (default ``spec.folder``).

    An existing bag there is replaced; other files of the folder (``expected.yaml``) are
    kept. Same spec, same bytes.

    Returns
    -------
    pathlib.Path
        The bag folder.
    """
    dest = Path(folder) if folder is not None else spec.folder
    msgs, _ = bag_messages(spec)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=dest.parent, prefix=f".{spec.name}.") as tmp:
        out = Path(tmp) / spec.name
        _write(out, msgs)
        dest.mkdir(exist_ok=True)
        for old in [*dest.glob("*.mcap"), dest / "metadata.yaml"]:
            if old.exists():
                old.unlink()
        for f in out.iterdir():
            shutil.move(str(f), str(dest / f.name))
    return dest


def generate_library(library: Library, names: Sequence[str] | None = None,
                     out_root: str | Path | None = None) -> list[dict[str, Any]]:
    """Regenerate the bags of a library (all, or ``names``).

    Parameters
    ----------
    library : Library
    names : sequence of str, optional
    out_root : str or pathlib.Path, optional
        Write ``<out_root>/<name>/`` instead of the library's own folders.

    Returns
    -------
    list of dict
        Per bag: name, folder, samples, bytes.
    """
    out = []
    for name in (names or library.names):
        spec = library[name]
        dest = spec.folder if out_root is None else Path(out_root) / spec.name
        generate_bag(spec, dest)
        size = sum(f.stat().st_size for f in dest.iterdir() if f.is_file())
        out.append({"name": spec.name, "folder": str(dest),
                    "samples": round(spec.duration / _sample_time(spec)), "bytes": size})
    return out


def _sample_time(spec: BagSpec) -> float:
    return float(load_scenario(spec.scenario).system.sample_time)
