"""One method registry (fd_monitor.core.methods): a method added in one place is loaded,
certified, dispatched and listed everywhere.

A toy method (a fixed bound on the first output) is registered in a registry of this test's
own, never in the shipped one: this module is its "one new module" (runtime, certificate
check and designer command line) and ``_toy_registry`` its "one line". Then the gain file it
writes is loaded and certified through the registry, the runtime is dispatched from it, and
``design --help`` lists it with its help line, while the shipped registry refuses it.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fd_monitor.commands import cli
from fd_monitor.commands import design as design_cmd
from fd_monitor.core.methods import (
    METHODS,
    RUNTIMES,
    Method,
    MethodRegistry,
    load_gains,
    runtime_for,
)
from fd_monitor.core.runtime import Runtime, RuntimeOutput
from fd_monitor.model.errors import GainFileError
from fd_monitor.model.gains import read_gains, save_gains
from fd_monitor.model.system import System, load_system

TOY_HELP = "toy bound on the first output (a test's method, never shipped)"


# -- the toy method: runtime, certificate check, designer command line -------------------------

class ToyRuntime(Runtime):
    """Alarm when |y_0| exceeds the gain file's ``results.bound``."""

    method = "toy"

    def __init__(self, system: System, gains: Any) -> None:
        super().__init__(system, gains)
        self.channels, self.units = ("y0",), (system.outputs[0],)
        self.bound = float(gains.results["bound"])

    def reset(self) -> None:
        pass

    def bridge(self, k: int, u: Any, y: Any, side: Mapping[str, Any] | None = None) -> None:
        pass

    def step(self, k: int, u: Any, y: Any,
             side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        r = np.abs(np.asarray(y, float)[:1])
        thr = np.array([self.bound])
        return RuntimeOutput(k, r, thr, r > thr, None, 0)


def check_toy(system: System, gains: Any) -> None:
    """The toy's certificate: the bound is positive and its recorded square matches it."""
    bound = float(gains.results["bound"])
    if not bound > 0 or gains.certificate["bound_squared"] != pytest.approx(bound ** 2):
        raise GainFileError(f"results.bound {bound}: not certified")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The toy designer's own option (SYSTEM and -o are the dispatcher's)."""
    parser.add_argument("--bound", type=float, default=1.0)


def run(args: argparse.Namespace) -> int:
    """Design the toy: write its gain file to -o."""
    system = load_system(args.system)
    save_gains(args.output, "toy", system, {}, {"bound": args.bound},
               {"bound_squared": args.bound ** 2}, {"name": "none", "status": "optimal"})
    return 0


def _toy_registry() -> MethodRegistry:
    reg = MethodRegistry(METHODS.values())
    reg.register(Method("toy", ToyRuntime, check_toy, TOY_HELP, __name__))  # the one line
    return reg


# -- the tests ----------------------------------------------------------------------------------

def _design_parser(reg: MethodRegistry, argv: list[str],
                   monkeypatch: pytest.MonkeyPatch) -> argparse.ArgumentParser:
    monkeypatch.setattr(cli, "ARGV", argv)     # what `design` reads to import one designer
    parser = argparse.ArgumentParser(prog="fd_monitor design")
    design_cmd.add_arguments(parser, reg)
    return parser


def test_a_registered_method_is_designed_loaded_certified_and_dispatched(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reg = _toy_registry()
    out = tmp_path / "toy.yaml"
    argv = ["design", "toy", "three_tank", "-o", str(out), "--bound", "0.5"]
    args = _design_parser(reg, argv, monkeypatch).parse_args(argv[1:])
    assert design_cmd.run(args) == 0 and out.is_file()

    plant = load_system("three_tank")
    gf = load_gains(out, plant, methods=reg)
    assert (gf.method, gf.certificate_status) == ("toy", "verified")
    rt = reg.runtime_for(plant, gf)
    assert type(rt) is ToyRuntime
    assert rt.step(0, [0.0, 0.0], [0.4, 0.0, 0.0]).alarm.tolist() == [False]
    assert rt.step(1, [0.0, 0.0], [-0.6, 0.0, 0.0]).alarm.tolist() == [True]

    # its certificate check is the one run: a bound whose certificate does not match is refused
    args = _design_parser(reg, argv, monkeypatch).parse_args(argv[1:])
    args.output, args.bound = str(tmp_path / "bad.yaml"), -0.5
    design_cmd.run(args)
    with pytest.raises(GainFileError, match=r"bad\.yaml: certificate does not hold: "
                                            r"results\.bound -0\.5"):
        load_gains(tmp_path / "bad.yaml", plant, methods=reg)

    # the shipped registry does not know it: refused in one line naming the known methods
    with pytest.raises(GainFileError, match=r"method: expected one of \['hinf_sc', "
                                            r"'hminus_switched', 'qb', 'thresholds'\], got 'toy'"):
        load_gains(out, plant)
    with pytest.raises(GainFileError, match="method 'toy': no runtime for it"):
        runtime_for(plant, gf)
    assert "toy" not in METHODS and "toy" not in RUNTIMES


def test_design_help_lists_every_method_with_its_help_line(
        monkeypatch: pytest.MonkeyPatch) -> None:
    text = " ".join(_design_parser(_toy_registry(), ["design", "--help"],
                                   monkeypatch).format_help().split())
    for name, m in (*METHODS.items(), ("toy", _toy_registry()["toy"])):
        assert f"{name} {m.help}" in text


def test_the_model_layer_knows_no_method() -> None:
    """The ground floor reads a gain file with the checks it is given: with none, every
    method is unknown (it has no table of its own to reach up with)."""
    with pytest.raises(GainFileError, match=r"method: expected one of \[\], got 'qb'"):
        read_gains("pwa_cascade_qb", {})


def test_the_registry_is_consistent() -> None:
    """One entry per method; each record's runtime runs that method, its designer module is
    the shipped command line, and a second entry of a name is refused."""
    assert list(METHODS) == ["qb", "thresholds", "hinf_sc", "hminus_switched"]
    for name, m in METHODS.items():
        assert m.runtime.method == name and RUNTIMES[name] is m.runtime
        assert m.designer == f"fd_monitor.commands.design_{name}"
        assert m.help and "\n" not in m.help
    with pytest.raises(ValueError, match="'qb' is registered already"):
        MethodRegistry(METHODS.values()).register(METHODS["qb"])
    with pytest.raises(ValueError, match="its runtime QBRuntime runs 'qb'"):
        Method("toy", METHODS["qb"].runtime, check_toy, TOY_HELP, __name__)


def test_chain_nodes_run_registered_methods_only() -> None:
    """The nodes dispatch on registry names (typed builders, no getattr by string)."""
    from fd_monitor.nodes.agei import AgeiNode
    from fd_monitor.nodes.bias_estimator import BiasEstimatorNode
    from fd_monitor.nodes.detector import DetectorNode
    from fd_monitor.nodes.monitor import MonitorNode
    from fd_monitor.nodes.observer import ObserverNode

    for node in (ObserverNode, DetectorNode, AgeiNode, BiasEstimatorNode):
        assert set(node.runtimes) <= set(METHODS) and "thresholds" in node.runtimes
        assert all(callable(b) for b in node.runtimes.values())
    assert list(MonitorNode.runtimes) == list(METHODS)
