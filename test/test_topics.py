"""The topic declarations (fd_monitor.wire.topics): names written once, layouts by field."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import Monitor
from fd_monitor.model.errors import MessageError
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.conversions import decode, to_msg
from fd_monitor.wire.topics import (
    BIAS_ESTIMATE,
    CHAIN_OUTPUTS,
    PLANT_TRUTH,
    RESIDUAL,
    STATE_ESTIMATE,
    TOPICS,
    runtime_estimate,
)

PKG = Path(__file__).resolve().parent.parent / "fd_monitor"
#: A string that is (or starts with) one of the package's topic names.
TOPIC_NAME = re.compile(r"^/?(plant|fd)/\w+|^/diagnostics$")


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String constants of a module that are not docstrings, with their line."""
    tree = ast.parse(path.read_text())
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docs.add(id(body[0].value))
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs]


def test_topic_names_are_written_in_wire_topics_only():
    """No module but wire/topics.py writes a topic name in code (core outputs name none)."""
    found = [f"{p.relative_to(PKG)}:{line}: {s!r}"
             for p in sorted(PKG.rglob("*.py")) if p.name != "topics.py" or p.parent.name != "wire"
             for line, s in _code_strings(p) if TOPIC_NAME.match(s)]
    assert found == []


def test_every_topic_declared_once():
    names = [t.absolute for t in TOPICS]
    assert len(set(names)) == len(names)
    assert "/plant/y" in names and "/diagnostics" in names
    assert all(not t.name.startswith("/") for t in TOPICS if t.name != "/diagnostics")


def test_layout_index_table_points_at_each_fields_labels():
    s = load_system("three_tank")
    lay = STATE_ESTIMATE.layout(s)
    assert lay.labels == ("mode", *s.states, *(f"y~{o}" for o in s.outputs), "restart",
                          "bridge")
    assert lay.labels[lay.index["mode"]] == "mode"
    assert lay.labels[lay.index["x_hat"]] == tuple(s.states)
    assert lay.labels[lay.index["y_tilde"]] == tuple(f"y~{o}" for o in s.outputs)
    assert lay.labels[lay.index["restart"]] == "restart"
    assert lay.labels[lay.index["bridge"]] == "bridge"
    bias = BIAS_ESTIMATE.layout(s)
    assert bias.labels[bias.index["isolated"]] == tuple(f"iso:{o}" for o in s.outputs)


def test_chain_topics_encode_the_core_payloads_by_field():
    """Every field of the chain's topics is in one core output's payload (or is restart or
    bridge), and
    a message encoded from them decodes back to each field's values through the index."""
    s = load_system("three_tank")
    mon = Monitor(s, load_gains("three_tank_thresholds", s))
    out = mon.step(0, np.zeros(s.nu), np.array([0.4, 0.2, 0.3]))
    pays = (out.observer.payload(), out.detector.payload(), out.agei.payload(),
            out.estimator.payload())
    flags = {"restart": True, "bridge": False}
    keys = {k for p in pays for k in p} | set(flags)
    merged = {k: v for p in pays for k, v in p.items()} | flags
    for topic in CHAIN_OUTPUTS:
        lay = topic.layout(s)
        assert {f for f, _ in lay.fields} <= keys, topic.name
        values = lay.encode(*pays, **flags)
        # the fused node's table: each field read from the payload that holds it
        src = (*pays, flags)
        for i, f, scalar in lay.sources(src):
            assert f in src[i]
            assert np.ndim(src[i][f]) == 0 if scalar else np.ndim(src[i][f]) == 1
        d = decode(to_msg(lay.labels, 7, values), topic.name, labels=lay.labels,
                   allow_nan=True)
        for f, _ in lay.fields:
            np.testing.assert_array_equal(np.ravel(d.values[lay.index[f]]),
                                          np.ravel(np.asarray(merged[f], dtype=float)))


def test_encode_refuses_a_payload_of_the_wrong_size():
    s = load_system("three_tank")
    lay = RESIDUAL.layout(s)
    with pytest.raises(ValueError, match="values for 6 labels"):
        lay.encode({"residual": np.zeros(2), "w": np.zeros(3)})
    with pytest.raises(ValueError, match="field w is in none"):
        lay.encode({"residual": np.zeros(3)})


def test_a_message_with_the_fields_in_another_order_is_refused():
    """Decoding is by label: a publisher that swaps two fields is refused, not misread."""
    s = load_system("three_tank")
    lay = RESIDUAL.layout(s)
    swapped = (*lay.labels[3:], *lay.labels[:3])
    with pytest.raises(MessageError, match="channels"):
        decode(to_msg(swapped, 0, np.zeros(6)), "fd/residual", labels=lay.labels)


def test_truth_labels_come_from_the_scenario():
    sc = load_scenario("three_tank_bias_h1")
    labels = PLANT_TRUTH.labels(sc)
    assert labels[0] == "mode"
    assert labels[1:1 + sc.system.n] == tuple(f"x.{x}" for x in sc.system.states)
    assert len(labels) == 1 + sc.system.n + len(sc.system.faults) + len(sc.rho_names)


def test_runtime_layouts_take_the_runtimes_channels():
    """A registry runtime publishes the declared topics with its own channels as labels."""
    s = load_system("three_tank")
    lay = RESIDUAL.channels(("g0", "g1"))
    assert lay.labels == ("g0", "g1") and lay.index == {"residual": slice(0, 2)}
    one = runtime_estimate(s, ("g0", "g1"), np.zeros(s.n))
    assert one.labels == ("mode", *(f"x.{x}" for x in s.states))
    bank = runtime_estimate(s, ("g0", "g1"), np.zeros((2, s.n)))
    assert bank.labels[1:1 + s.n] == tuple(f"g0.{x}" for x in s.states)
    assert bank.labels[bank.index["x_hat"]][-1] == f"g1.{s.states[-1]}"
    np.testing.assert_array_equal(
        bank.encode({"mode": 1, "x_hat": np.arange(2.0 * s.n).reshape(2, s.n)}),
        [1.0, *range(2 * s.n)])
    with pytest.raises(ValueError, match="no field"):
        STATE_ESTIMATE.with_labels({"nope": ("a",)})
    with pytest.raises(ValueError, match="one value"):
        STATE_ESTIMATE.with_labels({"mode": ("a", "b")})
