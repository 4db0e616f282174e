"""``python -m fd_monitor validate FILE``: check a plant file, a scenario or an adapter file and
summarise it.

An adapter file (:mod:`fd_monitor.wire.adapters`: ``inputs``/``outputs`` lists of
``{channel, topic, type, ...}`` mappings) is recognised by its content, or named with
``--adapter``, and checked on its own (:func:`~fd_monitor.wire.adapters.parse_adapter`); with
``--bag BAG`` it is a dry run of the offline reader
(:func:`~fd_monitor.wire.adapters.read_adapted`) over the bag: how its messages pair into
samples (the sample clock and the held topics with their message counts), the samples and
their k range, the sample time used, every hole and every message or sample left out, with
counts per reason. ``--system`` checks the mapping against a plant (and takes its sample
time); ``--sample-time`` overrides it.
"""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.commands._common import add_json_flag, print_json, print_table
from fd_monitor.model.errors import FdMonitorError, ScenarioError, SystemFileError
from fd_monitor.model.scenario import Scenario, load_scenario
from fd_monitor.model.system import System, load_system
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["adapter_dry_run", "adapter_summary", "add_arguments", "run", "system_summary"]

#: Lines of skips and holes the human output lists (``--json`` lists every one).
_LIST_MAX = 40
#: Samples the dry run shows (the pairing of the first messages).
_FIRST = 5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``validate``."""
    parser.add_argument("file", metavar="FILE",
                        help="plant file or scenario file (a path, or a shipped name)")
    parser.add_argument("--scenario", action="store_true",
                        help="treat FILE as a scenario (automatic for files with a "
                             "'system:' key or shipped scenario names)")
    parser.add_argument("--adapter", action="store_true",
                        help="treat FILE as an adapter file, or a shipped adapter name "
                             "(automatic for files whose inputs/outputs are "
                             "{channel, topic, type} mappings)")
    parser.add_argument("--bag", default=None, metavar="BAG",
                        help="adapter files: dry run over this robot bag (how its messages "
                             "pair into samples; holes and skips with counts per reason)")
    parser.add_argument("--system", default=None, metavar="SYSTEM",
                        help="adapter files: check the mapping against this plant (its "
                             "inputs, outputs and sample time)")
    parser.add_argument("--sample-time", type=float, default=None, metavar="S",
                        help="adapter dry run: sample time, s (default: the plant's with "
                             "--system, else from the clock's stamps)")
    add_json_flag(parser)


def system_summary(system: System) -> dict[str, Any]:
    """Summary of a plant: sizes, modes, guards, bounds and its SHA-256."""
    return {
        "name": system.name,
        "file": system.source,
        "sha256": system.sha256,
        "sample_time": system.sample_time,
        "states": list(system.states),
        "inputs": list(system.inputs),
        "outputs": list(system.outputs),
        "disturbances": list(system.disturbances),
        "modes": [{"name": m.name, "dynamics": m.dynamics,
                   "time": m.time if m.dynamics == "linear" else "discrete",
                   "model": m.model,
                   "max_uncertainty": float(np.max(m.uncertainty, initial=0.0))}
                  for m in system.modes],
        "guards": [{"name": g.name, "kind": g.kind, "from": system.modes[g.source].name,
                    "to": system.modes[g.target].name,
                    "when": " and ".join(f"{c.var} {c.op} {c.value:g}" for c in g.conditions)}
                   for g in system.guards],
        "faults": [{"name": f.name, "kind": f.kind} for f in system.faults],
        "measurement_noise": system.measurement_noise,
        "disturbance_bound": system.disturbance_bound,
        "initial": {"mode": system.modes[system.initial_mode].name,
                    "state": system.initial_state},
    }


def _scenario_summary(sc: Scenario) -> dict[str, Any]:
    return {
        "scenario": sc.name,
        "file": sc.source,
        "system": sc.system.name,
        "system_sha256": sc.system.sha256,
        "duration": sc.duration,
        "samples": sc.n_samples,
        "seed": sc.seed,
        "faults": [{"channel": sc.system.faults[f.channel].name, "profile": f.profile,
                    "time": f.time, "magnitude": f.magnitude} for f in sc.faults],
    }


def _is_scenario(source: str) -> bool:
    p = Path(source)
    if p.is_file():
        data = read_yaml(p, ScenarioError)
        return isinstance(data, dict) and "system" in data and "modes" not in data
    try:
        load_system(source)
        return False
    except SystemFileError as exc:
        try:
            load_scenario(source)
        except ScenarioError:
            raise SystemFileError(f"{source}: neither a shipped plant nor a shipped scenario "
                                  f"({exc})") from None
        return True


def _is_adapter_file(source: str) -> bool:
    """Whether ``source`` is a file that reads as an adapter file: ``inputs``/``outputs``
    lists of mappings, or those keys without a plant's ``name``/``modes`` or a scenario's
    ``system`` (a broken adapter file is then checked as one, and its error names the key)."""
    p = Path(source)
    if not p.is_file():
        return False
    doc = read_yaml(p, SystemFileError)
    if not isinstance(doc, Mapping):
        return False
    lists = [doc[r] for r in ("inputs", "outputs") if isinstance(doc.get(r), list)]
    if any(isinstance(e, Mapping) for lst in lists for e in lst):
        return True
    return bool({"inputs", "outputs"} & set(doc)) and not {"name", "modes", "system"} & set(doc)


def adapter_summary(adapter: Any) -> dict[str, Any]:
    """An adapter file's channels and topics: per channel its role, topic, type and field;
    per topic whether it is the sample clock or held, and what times it (header stamp or
    receive time)."""
    from fd_monitor.wire.adapters import ADAPTER_TYPES

    return {
        "file": adapter.source,
        "clock_topic": adapter.clock_topic,
        "channels": [{"channel": c.name, "role": role, "topic": c.topic, "type": c.msgtype,
                      "field": c.where[len(c.topic):]}
                     for role, chans in (("input", adapter.inputs),
                                         ("output", adapter.outputs)) for c in chans],
        "topics": [{"topic": t, "type": ty,
                    "role": "sample clock" if t == adapter.clock_topic else "held",
                    "time": "header.stamp" if ADAPTER_TYPES[ty][0] else "receive time"}
                   for t, ty in adapter.topics.items()],
    }


def _runs(ks: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive runs ``(first, last)`` of the indices missing between sorted ``ks``."""
    gaps = np.flatnonzero(np.diff(ks) > 1)
    return [(int(ks[i]) + 1, int(ks[i + 1]) - 1) for i in gaps]


def adapter_dry_run(adapter: Any, bag: str, system: Any = None,
                    sample_time: float | None = None) -> dict[str, Any]:
    """How a robot bag's messages pair into samples through ``adapter`` (the offline reader,
    :func:`~fd_monitor.wire.adapters.read_adapted`, run and described).

    Returns
    -------
    dict
        ``bag``, ``messages`` (topic -> count of the mapped topics), ``sample_time`` (s) and
        ``sample_time_from`` (``--sample-time``, the plant, or the clock's stamps),
        ``samples``, ``k_first``, ``k_last``, ``holes`` (``[{first, last, samples}]``),
        ``skipped`` (``[{kind, message}]``: messages and samples left out), ``counts``
        (reason -> count: ``hole`` counts missing samples, every other kind its entries),
        ``first_samples`` (``[{k, t, u, y}]``, t in s since the first sample).
    """
    from fd_monitor.wire.adapters import read_adapted
    from fd_monitor.wire.bags import bag_topics

    if not Path(bag).exists():
        raise FdMonitorError(f"--bag {bag}: no such bag")
    s = read_adapted(bag, adapter, sample_time=sample_time, system=system)
    present = bag_topics(bag)
    holes = [{"first": a, "last": b, "samples": b - a + 1} for a, b in _runs(s.k)]
    counts: Counter[str] = Counter(kind for kind, _line in s.errors)
    if holes:
        counts["hole"] = sum(h["samples"] for h in holes)
    return {
        "bag": str(bag),
        "messages": {t: present.get(t, ("", 0))[1] for t in adapter.topics},
        "sample_time": float(s.sample_time),
        "sample_time_from": ("--sample-time" if sample_time is not None else
                             f"plant {system.name}" if system is not None else
                             f"the stamps of {s.clock_topic} (median step)"),
        "samples": len(s.k),
        "k_first": int(s.k[0]),
        "k_last": int(s.k[-1]),
        "holes": holes,
        "skipped": [{"kind": kind, "message": line} for kind, line in s.errors],
        "counts": dict(sorted(counts.items())),
        "first_samples": [{"k": int(s.k[i]), "t": float(s.t[i]),
                           "u": dict(zip(s.inputs, map(float, s.u[i]))),
                           "y": dict(zip(s.outputs, map(float, s.y[i])))}
                          for i in range(min(_FIRST, len(s.k)))],
    }


def _columns(adapter: Any) -> list[str]:
    """Column names of u then y: ``u.effort``, ``y.velocity``."""
    return [f"u.{c.name}" for c in adapter.inputs] + [f"y.{c.name}" for c in adapter.outputs]


def _validate_adapter(args: argparse.Namespace) -> int:
    """``validate ADAPTER.yaml [--system SYSTEM] [--bag BAG]``."""
    from fd_monitor.wire.adapters import load_adapter

    ad = load_adapter(args.file)
    system = None
    if args.system is not None:
        system = load_system(args.system)
        ad = ad.for_system(system)
    if args.sample_time is not None and not 0 < args.sample_time < float("inf"):
        raise FdMonitorError(f"--sample-time {args.sample_time}: expected a number > 0 (s)")
    summary = adapter_summary(ad)
    dry = None if args.bag is None else adapter_dry_run(ad, args.bag, system,
                                                        args.sample_time)
    if args.json:
        print_json({"valid": True, **summary, **({} if system is None else
                                                 {"system": system.name}),
                    **({} if dry is None else {"dry_run": dry})})
        return 0
    print(f"valid adapter {ad.source}: {len(ad.inputs)} input(s), {len(ad.outputs)} "
          f"output(s)" + ("" if system is None else f", the channels of plant {system.name}")
          + f"; sample clock {ad.clock_topic}")
    print()
    print_table([(c["channel"], c["role"], c["topic"], c["type"], c["field"])
                 for c in summary["channels"]],
                header=("channel", "role", "topic", "type", "field"))
    if dry is None:
        return 0
    print()
    print(f"dry run over {dry['bag']}: every {ad.clock_topic} message is a sample, the other "
          f"topics are held (latest value before it)")
    print_table([(t["topic"], t["role"], t["time"], dry["messages"][t["topic"]])
                 for t in summary["topics"]], header=("topic", "role", "time", "messages"))
    print()
    print_table([(f["k"], f"{f['t']:.6f}",
                  *(f"{v:.6g}" for v in (*f["u"].values(), *f["y"].values())))
                 for f in dry["first_samples"]],
                header=("k", "t_s", *_columns(ad)), title="first samples")
    print()
    print(f"sample time {dry['sample_time']:.9g} s (from {dry['sample_time_from']}); "
          f"{dry['samples']} samples, k {dry['k_first']}..{dry['k_last']}; "
          + (", ".join(f"{n} {r}" for r, n in dry["counts"].items()) or "no hole, nothing "
             "skipped"))
    rows = ([("hole", f"k {h['first']}..{h['last']}: no sample ({h['samples']})")
             for h in dry["holes"]]
            + [(e["kind"], e["message"]) for e in dry["skipped"]])
    if rows:
        print()
        print_table(rows[:_LIST_MAX], header=("reason", "what"))
        if len(rows) > _LIST_MAX:
            print(f"... and {len(rows) - _LIST_MAX} more (--json lists every one)")
    return 0


def run(args: argparse.Namespace) -> int:
    """Validate and print; errors propagate as one-line FdMonitorError messages."""
    if args.adapter or (not args.scenario and _is_adapter_file(args.file)):
        return _validate_adapter(args)
    for flag, given in (("--bag", args.bag), ("--system", args.system),
                        ("--sample-time", args.sample_time)):
        if given is not None:
            raise FdMonitorError(f"{flag}: only for an adapter file ({args.file} is not one; "
                                 f"--adapter to read it as one)")
    if args.scenario or _is_scenario(args.file):
        sc = load_scenario(args.file)
        summary = _scenario_summary(sc)
        if args.json:
            print_json({"valid": True, **summary})
            return 0
        print(f"valid scenario {sc.name} ({sc.source}) for plant {sc.system.name} "
              f"{sc.system.sha256[:12]}: {sc.duration:g} s = {sc.n_samples} samples, "
              f"seed {sc.seed}")
        print_table([(f["channel"], f["profile"], f["time"], f["magnitude"])
                     for f in summary["faults"]], header=("fault", "profile", "time [s]",
                                                          "magnitude"))
        return 0
    system = load_system(args.file)
    summary = system_summary(system)
    if args.json:
        print_json({"valid": True, **summary})
        return 0
    print(f"valid plant {system.name} ({system.source})")
    print(f"sha256 {system.sha256}")
    print(f"{system.n} states {list(system.states)}, {system.nu} inputs "
          f"{list(system.inputs)}, {system.ny} outputs {list(system.outputs)}, "
          f"{system.nw} disturbances; Ts = {system.sample_time:g} s")
    print()
    print_table([(m["name"], m["dynamics"], m["time"], m["model"] or "-",
                  m["max_uncertainty"]) for m in summary["modes"]],
                header=("mode", "dynamics", "time", "model", "max |eta|"))
    if summary["guards"]:
        print()
        print_table([(g["name"], g["kind"], g["from"], g["to"], g["when"])
                     for g in summary["guards"]],
                    header=("guard", "kind", "from", "to", "when"))
    if summary["faults"]:
        print()
        print_table([(f["name"], f["kind"]) for f in summary["faults"]],
                    header=("fault channel", "kind"))
    return 0
