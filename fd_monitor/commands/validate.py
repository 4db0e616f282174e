"""``python -m fd_monitor validate FILE``: check a plant file (or a scenario) and summarise it."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.commands._common import add_json_flag, print_json, print_table
from fd_monitor.model.errors import ScenarioError, SystemFileError
from fd_monitor.model.scenario import Scenario, load_scenario
from fd_monitor.model.system import System, load_system
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["add_arguments", "run", "system_summary"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``validate``."""
    parser.add_argument("file", metavar="FILE",
                        help="plant file or scenario file (a path, or a shipped name)")
    parser.add_argument("--scenario", action="store_true",
                        help="treat FILE as a scenario (automatic for files with a "
                             "'system:' key or shipped scenario names)")
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


def run(args: argparse.Namespace) -> int:
    """Validate and print; errors propagate as one-line FdMonitorError messages."""
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
