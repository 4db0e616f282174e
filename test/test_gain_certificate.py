"""The gain-file certificate covers every number: any single edit of a shipped file is refused.

Issue 12: 277 of 524 +-0.1 % edits of single numbers (estimator, AGEI, isolation parameters,
Lambda, ...) still loaded as "verified". The designer now writes a digest of every key
(:func:`fd_monitor.model.gains.gain_digest`), re-checked at load before anything else.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from fd_monitor.core.methods import gains_from_doc, load_gains
from fd_monitor.model.errors import GainFileError
from fd_monitor.model.gains import write_gain_doc
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.system import load_system

GAIN_DIR = find_config_file("three_tank_thresholds", "gains", GainFileError).parent
SHIPPED = sorted(GAIN_DIR.glob("*.yaml"))


def _numbers(node: Any, path: str) -> Iterator[tuple[str, Any, Any]]:
    """(key path of the leaf, container, index) of every number in a parsed YAML tree."""
    items = node.items() if isinstance(node, dict) else enumerate(node)
    for k, v in items:
        sub = (f"{path}.{k}" if path else str(k)) if isinstance(node, dict) else path
        if isinstance(v, bool):
            continue
        if isinstance(v, (int, float)):
            yield sub, node, k
        elif isinstance(v, (dict, list)):
            # lists of mappings are named by index in the digest's key paths
            if isinstance(v, list) and any(isinstance(e, dict) for e in v):
                for i, e in enumerate(v):
                    if isinstance(e, (dict, list)):
                        yield from _numbers(e, f"{sub}[{i}]")
            else:
                yield from _numbers(v, sub)


def _edit(v: Any, sign: int) -> Any:
    """The value +-0.1 % (1e-6 for a zero); ints stay ints when the change is >= 1."""
    if v == 0:
        return 1e-6 * sign
    new = v * (1 + sign * 1e-3)
    return round(new) if isinstance(v, int) and round(new) != v else new


def _system(doc: dict) -> Any:
    return load_system(doc["system"]["name"])


def test_shipped_gain_files_load_verified():
    assert len(SHIPPED) >= 8
    for f in SHIPPED:
        doc = yaml.safe_load(f.read_text(encoding="utf-8"))
        assert load_gains(f, _system(doc)).certificate_status == "verified", f.name


@pytest.mark.parametrize("gain_file", SHIPPED, ids=lambda p: p.stem)
def test_every_single_number_edit_is_refused(gain_file: Path):
    """Certificate sweep: each number of the file, +0.1 % or -0.1 % (alternating), refused
    with the key path of the edit named."""
    doc = yaml.safe_load(gain_file.read_text(encoding="utf-8"))
    system = _system(doc)
    edits = [e for e in _numbers(doc, "") if not e[0].startswith("digest")]
    assert len(edits) > 20
    accepted = []
    for i, (where, node, key) in enumerate(edits):
        old = node[key]
        node[key] = _edit(old, 1 if i % 2 == 0 else -1)
        try:
            gains_from_doc(doc, gain_file, system)
        except GainFileError as exc:
            assert where in str(exc), (where, str(exc))
        else:
            accepted.append(where)
        finally:
            node[key] = old
    assert accepted == [], f"{len(accepted)} of {len(edits)} edits loaded: {accepted[:5]}"
    # the untouched document still loads
    assert gains_from_doc(doc, gain_file, system).certificate_status == "verified"


def test_edit_in_a_file_names_the_key_path(tmp_path):
    """Through the file: an edited isolation factor (not re-derivable from the plant)."""
    src = find_config_file("three_tank_thresholds", "gains", GainFileError)
    text = src.read_text(encoding="utf-8")
    assert "  isolation_factor: 1.0\n" in text
    p = tmp_path / "edited.yaml"
    p.write_text(text.replace("  isolation_factor: 1.0\n", "  isolation_factor: 1.001\n"))
    with pytest.raises(GainFileError, match=r"edited\.yaml: edited after design: "
                                            r"parameters\.isolation_factor changed"):
        load_gains(p, load_system("three_tank"))
    # a key added or removed is named too
    doc = yaml.safe_load(text)
    doc["results"]["extra"] = 1.0
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(GainFileError, match=r"results\.extra added"):
        load_gains(p)
    del doc["results"]["extra"], doc["digest"]
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(GainFileError, match=r"digest: missing .*design thresholds three_tank"):
        load_gains(p)


def test_writer_round_trip_is_exact(tmp_path):
    """Re-writing a shipped file through the one writer gives the same bytes (the digest is
    computed on what YAML parses back, so a designer's file always loads)."""
    for f in SHIPPED:
        doc = yaml.safe_load(f.read_text(encoding="utf-8"))
        out = write_gain_doc(tmp_path / f.name, copy.deepcopy(doc))
        assert out.read_bytes() == f.read_bytes(), f.name


def test_unverified_load_skips_the_digest(tmp_path):
    """verify=False (used to read the plant name first) does not check anything."""
    src = find_config_file("pwa_cascade_qb", "gains", GainFileError)
    doc = yaml.safe_load(src.read_text(encoding="utf-8"))
    doc["results"]["beta"] = 0.5
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(doc))
    assert load_gains(p, verify=False).certificate_status == "unchecked"
    with pytest.raises(GainFileError, match=r"results\.beta changed"):
        load_gains(p, load_system("pwa_cascade"))
