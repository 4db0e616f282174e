"""``python -m fd_monitor identify``: a plant file from bags (issue 14 item 1).

Synthetic plants with known matrices (recovery, hybrid structure, mode channel, the file the
rest of the tool reads) and every refusal of data it cannot identify from. The three_tank
acceptance is test/test_identify_three_tank.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fd_monitor.analysis.identify import (
    Dataset,
    identify,
    identify_bags,
    load_dataset,
    plot_validation,
    write_plant,
)
from fd_monitor.commands.cli import main as cli_main
from fd_monitor.core.identify import (
    IdentificationError,
    clip_radius,
    noise_bound,
    spectral_radius,
    stlsq,
    uncertainty_bound,
)
from fd_monitor.model.errors import BagError
from fd_monitor.model.system import load_system
from fd_monitor.wire.bag_reader import arrays_from
from fd_monitor.wire.bag_writer import write_bag

A_TRUE = np.array([[0.95, 0.02], [0.0, 0.90]])
B_TRUE = np.array([[0.10, 0.0], [0.0, 0.20]])
C_TRUE = np.array([0.01, -0.02])
V_BAR = 0.002          # |v| <= 2 mm, uniform
ETA_BAR = 1e-4
TS = 0.1


def _inputs(rng: np.random.Generator, K: int, hold: int = 7) -> np.ndarray:
    """Piecewise-constant random levels in [0, 1] (open-loop excitation), (K, 2)."""
    levels = rng.uniform(0.0, 1.0, (K // hold + 1, 2))
    return np.repeat(levels, hold, axis=0)[:K]


def _simulate(seed: int, K: int = 3000, *, hybrid: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u (K, 2), y (K, 2), true mode (K,) of the synthetic plant.

    hybrid: above x1 = 1 the first state leaks harder (A11 0.95 -> 0.85, offset so that the
    two modes agree at the switching level, like an overflow pipe).
    """
    rng = np.random.default_rng(seed)
    u = _inputs(rng, K)
    x = np.array([0.4, 0.1])
    X = np.empty((K, 2))
    q = np.zeros(K, dtype=int)
    for k in range(K):
        X[k] = x
        hi = hybrid and x[0] > 1.0
        q[k] = int(hi)
        A = A_TRUE.copy()
        c = C_TRUE.copy()
        if hi:
            A[0, 0] -= 0.10
            c[0] += 0.10 * 1.0
        x = A @ x + B_TRUE @ u[k] + c + rng.uniform(-ETA_BAR, ETA_BAR, 2)
    y = X + rng.uniform(-V_BAR, V_BAR, (K, 2))
    return u, y, q


def _bag(path: Path, u: np.ndarray, y: np.ndarray, *, mode: np.ndarray | None = None,
         y_labels: tuple[str, ...] = ("y1", "y2"), skip_u: bool = False) -> Path:
    k = np.arange(y.shape[0])
    ns = np.rint(k * TS * 1e9).astype(np.int64)
    arrs = [arrays_from("/plant/y", y_labels, k, y, ns)]
    if not skip_u:
        arrs.insert(0, arrays_from("/plant/u", ("u1", "u2"), k, u, ns))
    if mode is not None:
        arrs.append(arrays_from("/plant/mode", ("mode",), k, mode[:, None].astype(float), ns))
    return write_bag(path, arrs)


@pytest.fixture(scope="module")
def linear_bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("ident")
    return [_bag(d / f"lin{s}", *_simulate(s)[:2]) for s in (1, 2, 3)]


@pytest.fixture(scope="module")
def hybrid_bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("ident_h")
    out = []
    for s in (11, 12, 13):
        u, y, q = _simulate(s, hybrid=True)
        out.append(_bag(d / f"hyb{s}", u, y, mode=q))
    return out


# ---------------------------------------------------------------- numerics (core)

def test_stlsq_drops_the_terms_that_are_not_there():
    rng = np.random.default_rng(0)
    Th = rng.normal(size=(500, 4))
    Y = Th @ np.array([[1.0], [0.0], [-2.0], [0.0]]) + 1e-3 * rng.normal(size=(500, 1))
    Xi = stlsq(Th, Y, 0.05)
    assert Xi[1, 0] == 0.0 and Xi[3, 0] == 0.0
    np.testing.assert_allclose(Xi[[0, 2], 0], [1.0, -2.0], atol=1e-3)


def test_noise_bound_is_the_smallest_that_explains_the_errors():
    A = np.array([[0.5, 0.0], [0.0, 1.0]])
    peaks = [np.array([0.3, 0.4])]
    v_bar, v = noise_bound(peaks, [A], 1.0)
    np.testing.assert_allclose(v, [0.2, 0.2], atol=1e-9)   # (1 + 0.5) 0.2 = 0.3, 2 x 0.2 = 0.4
    v_bar, _ = noise_bound(peaks, [A], 1.5)
    np.testing.assert_allclose(v_bar, [0.3, 0.3], atol=1e-9)


def test_uncertainty_bound_sees_a_systematic_error_the_noise_cannot_explain():
    rng = np.random.default_rng(1)
    v = rng.uniform(-1.0, 1.0, (2001, 1))
    e = v[1:] - v[:-1]                      # A = 1: pure noise, explained
    A = np.eye(1)
    eta, excess, n = uncertainty_bound([e], A, np.array([1.0]), 20, 1.2)
    assert n == 2000 and excess[0] == 0.0 and eta[0] == 0.0
    eta, excess, _ = uncertainty_bound([e + 0.05], A, np.array([1.0]), 20, 1.2)
    # window of 20: noise term 2/20 = 0.1, the offset 0.05 sticks out by up to 0.05
    assert 0.0 < excess[0] <= 0.05 + 1e-12
    assert eta[0] == pytest.approx(1.2 * excess[0])


def test_clip_radius_makes_a_matrix_schur_and_keeps_it_real():
    A = np.array([[1.001, 0.2], [0.0, 0.5]])
    As = clip_radius(A, 0.999)
    assert np.isrealobj(As)
    assert spectral_radius(As) == pytest.approx(0.999)
    np.testing.assert_allclose(sorted(np.abs(np.linalg.eigvals(As))), [0.5, 0.999], atol=1e-12)


# ---------------------------------------------------------------- identification

def test_linear_plant_recovered_with_its_bounds(linear_bags, tmp_path):
    res = identify_bags(linear_bags[:1], holdout=linear_bags[1:2], name="synthetic",
                        model="affine")
    M = res.system.modes[0]
    np.testing.assert_allclose(M.A, A_TRUE, atol=0.01)
    np.testing.assert_allclose(M.B, B_TRUE, atol=0.01)
    np.testing.assert_allclose(M.offset, C_TRUE, atol=0.01)
    # the noise explained by the one-step errors is the true bound (within sampling), times
    # the margin 1.2 in the file
    v = np.asarray(res.summary["measurement_noise"]["explained"])
    assert np.all(v > 0.9 * V_BAR) and np.all(v < 1.05 * V_BAR)
    np.testing.assert_allclose(res.system.measurement_noise, 1.2 * v)
    assert res.summary["measurement_noise"]["samples"] == 2999
    # one-step errors of a third, unseen run within the stated bound in every sample
    chk = res.one_step(load_dataset(linear_bags[2]))
    assert chk["error"].shape == (2999, 2)
    assert np.all(np.abs(chk["error"]) <= chk["bound"])
    # the envelope is what the data covered
    env = res.doc["envelope"]["states"]["y1"]
    ys = np.vstack([load_dataset(b).y for b in linear_bags[:2]])
    assert env == [float(ys[:, 0].min()), float(ys[:, 0].max())]


def test_written_file_is_a_plant_the_tool_reads_and_reproducible(linear_bags, tmp_path):
    out = tmp_path / "plant.yaml"
    args = ["identify", str(linear_bags[0]), "--holdout", str(linear_bags[1]), "-o", str(out),
            "--json"]
    assert cli_main(args) == 0
    first = out.read_text()
    sysm = load_system(out)
    assert sysm.name == "plant" and sysm.states == ("y1", "y2")
    assert sysm.envelope is not None
    assert "sha256" in first and "fd_monitor identify" in first
    assert cli_main([*args, "--force"]) == 0
    assert out.read_text() == first                       # no date: byte for byte
    assert cli_main(["validate", str(out)]) == 0


def test_auto_picks_the_lowest_held_out_error_and_sparse_zeroes_the_missing_coupling(
        linear_bags):
    res = identify_bags(linear_bags[:1], holdout=linear_bags[1:2], name="p", model="auto")
    cands = res.summary["candidates"]
    assert {c["model"] for c in cands} == {"linear", "affine", "sparse"}
    assert {c["estimator"] for c in cands} == {"ls", "iv", "n4sid"}
    # open loop (no input reacts to the noise): every candidate may be chosen, by held-out
    # simulation error (issue 20)
    assert res.summary["closed_loop"]["inputs"] == []
    (best,) = [c for c in cands if c["chosen"]]
    assert best["simulation_error"] <= min(c["simulation_error"] for c in cands) + 1e-9
    assert (res.summary["model"], res.summary["estimator"]) == (best["model"],
                                                                best["estimator"])
    sp = identify_bags(linear_bags[:1], holdout=linear_bags[1:2], name="p", model="sparse",
                       sparsity=0.05)
    A = sp.system.modes[0].A
    assert A[1, 0] == 0.0                                   # x2 does not depend on x1
    assert sp.system.modes[0].B[0, 1] == 0.0 and sp.system.modes[0].B[1, 0] == 0.0


def test_guard_gives_one_mode_per_side_with_guards_both_ways(hybrid_bags):
    res = identify_bags(hybrid_bags[:1], holdout=hybrid_bags[1:2], name="hyb",
                        guards=["y1 > 1.0"], modes="full", model="affine")
    names = res.system.mode_names
    assert set(names) == {"y1_le_1p0", "y1_gt_1p0"}
    lo, hi = (res.system.modes[names.index(m)] for m in ("y1_le_1p0", "y1_gt_1p0"))
    assert lo.A[0, 0] == pytest.approx(0.95, abs=0.02)
    assert hi.A[0, 0] == pytest.approx(0.85, abs=0.02)
    g = {(res.system.mode_names[x.source], x.conditions[0].op) for x in res.system.guards}
    assert g == {("y1_le_1p0", ">"), ("y1_gt_1p0", "<=")}
    assert all(x.kind == "autonomous" for x in res.system.guards)
    env = res.doc["envelope"]["modes"]
    assert env["y1_le_1p0"]["states"]["y1"][1] <= 1.0 < env["y1_gt_1p0"]["states"]["y1"][0] + 1e-12
    chk = res.one_step(load_dataset(hybrid_bags[2]))
    assert np.all(np.abs(chk["error"]) <= chk["bound"])


def test_mode_channel_gives_a_switched_plant(hybrid_bags):
    res = identify_bags(hybrid_bags[:1], holdout=hybrid_bags[1:2], name="sw",
                        mode_topic="/plant/mode", modes="full", model="affine")
    assert res.system.mode_names == ("mode_0", "mode_1")
    assert res.doc["switching"] == "arbitrary" and "guards" not in res.doc
    assert res.system.modes[1].A[0, 0] == pytest.approx(0.85, abs=0.02)


def test_split_fraction_holds_out_the_tail(linear_bags):
    res = identify_bags(linear_bags[:1], name="p", model="affine", split=0.25)
    assert res.summary["validation_samples"] == 749       # samples 2250..2999
    assert res.summary["fit_samples"] == 2249
    assert res.summary["holdout"] == "last 0.25 of each fit bag"


def test_plot_is_written(linear_bags, tmp_path):
    res = identify_bags(linear_bags[:1], holdout=linear_bags[1:2], name="p", model="affine")
    png = plot_validation(res, tmp_path / "v.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------- refusals, one line each

def _one_line(capsys, argv):
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("fd_monitor: error: ") and "\n" not in err
    return err


def test_too_short(tmp_path, capsys):
    u, y, _ = _simulate(5, K=20)
    bag = _bag(tmp_path / "short", u, y)
    err = _one_line(capsys, ["identify", str(bag), "-o", str(tmp_path / "p.yaml")])
    assert "too short: 13 one-step samples in the fit data, at least 50 needed" in err
    assert not (tmp_path / "p.yaml").exists()


def test_no_excitation_names_the_input(tmp_path, capsys):
    u, y, _ = _simulate(6)
    u[:, 1] = 0.3
    bag = _bag(tmp_path / "flat", u, y)
    err = _one_line(capsys, ["identify", str(bag), "-o", str(tmp_path / "p.yaml")])
    assert "input u2 is constant (0.3) over all 2099 one-step samples" in err
    assert "no excitation" in err
    # ... and --exclude-input takes it out of the fit
    assert cli_main(["identify", str(bag), "-o", str(tmp_path / "p.yaml"),
                     "--exclude-input", "u2"]) == 0


def test_nan_names_topic_channel_and_sample(tmp_path, capsys):
    # analyze's input policy (issue 26 item 1): a NaN sample is refused and counted, the fit
    # goes on without it (no one-step pair across it), and --strict refuses the bag
    u, y, _ = _simulate(7)
    y[57, 1] = np.nan
    bag = _bag(tmp_path / "nan", u, y)
    err = _one_line(capsys, ["identify", str(bag), "-o", str(tmp_path / "p.yaml"), "--strict"])
    assert "1 of 3000 samples not used (non_finite 1)" in err and "--strict" in err
    assert not (tmp_path / "p.yaml").exists()
    u[12, 0] = np.inf
    y[57, 1] = 0.1
    bag = _bag(tmp_path / "inf", u, y)
    assert cli_main(["identify", str(bag), "-o", str(tmp_path / "p.yaml"), "--json"]) == 0
    out, err = capsys.readouterr()
    assert "1 of 3000 samples not used (non_finite 1)" in err
    assert json.loads(out)["integrity"][str(bag)]["refused_samples"] == {"non_finite": 1}


def test_mismatched_channels_between_bags(tmp_path, capsys, linear_bags):
    u, y, _ = _simulate(8)
    other = _bag(tmp_path / "other", u, y, y_labels=("y1", "z2"))
    err = _one_line(capsys, ["identify", str(linear_bags[0]), str(other),
                             "-o", str(tmp_path / "p.yaml")])
    assert "output channels [y1, z2] differ from" in err


def test_missing_topic(tmp_path, capsys):
    u, y, _ = _simulate(9)
    bag = _bag(tmp_path / "no_u", u, y, skip_u=True)
    err = _one_line(capsys, ["identify", str(bag), "-o", str(tmp_path / "p.yaml")])
    assert "no topic /plant/u" in err
    with pytest.raises(BagError, match="no such bag"):
        load_dataset(tmp_path / "nothing")


def test_bad_guards_and_options(linear_bags, tmp_path, capsys):
    o = str(tmp_path / "p.yaml")
    b = str(linear_bags[0])
    assert "is not a channel" in _one_line(capsys, ["identify", b, "-o", o, "--guard", "h9 > 1"])
    assert "expected 'CHANNEL OP VALUE'" in _one_line(
        capsys, ["identify", b, "-o", o, "--guard", "y1 = 1"])
    assert cli_main(["identify", b, "-o", o, "--margin", "0.5"]) == 2   # argparse's line
    assert capsys.readouterr().err == ("fd_monitor identify: error: argument --margin: "
                                       "expected a finite number >= 1, got '0.5'\n")
    Path(o).write_text("x")
    assert "exists (would overwrite; use --force)" in _one_line(capsys, ["identify", b, "-o", o])


def test_dataset_from_arrays_is_checked():
    k = np.arange(100)
    u = np.zeros((100, 1))
    y = np.zeros((100, 1))
    y[3, 0] = np.nan
    with pytest.raises(IdentificationError, match="channel y sample 3: NaN"):
        identify([Dataset("arr", ("u",), ("y",), k, u, y, TS)], name="p")


def test_json_summary_has_the_bounds_and_their_sample_counts(linear_bags, tmp_path, capsys):
    out = tmp_path / "p.yaml"
    assert cli_main(["identify", str(linear_bags[0]), "--holdout", str(linear_bags[1]),
                     "-o", str(out), "--json", "--model", "affine"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["plant_file"] == str(out)
    assert doc["measurement_noise"]["samples"] == 2999
    (mode,) = doc["modes"]
    assert mode["uncertainty_samples"] == 2999 and len(mode["one_step_bound"]) == 2
    assert doc["fit_bags"][0]["sha256"] and len(doc["fit_bags"][0]["sha256"]) == 64
    plant = yaml.safe_load(out.read_text())
    assert plant["modes"]["nominal"]["uncertainty"] == mode["uncertainty"]
    with pytest.raises(IdentificationError, match="is a folder"):
        write_plant(identify_bags(linear_bags[:1], name="p", model="affine"), tmp_path)
