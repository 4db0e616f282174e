"""QB designer: paper reproduction (Sec. VI), certificate, properties and errors."""

from __future__ import annotations

import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from fd_monitor.core.methods import load_gains
from fd_monitor.core.qb_certificate import check_certificate, lmi_blocks
from fd_monitor.core.qb_model import qb_model, spectral_abscissa, unobservable_unstable
from fd_monitor.design.qb import design_qb, write_gain_file
from fd_monitor.model.errors import DesignError, GainFileError
from fd_monitor.model.gains import write_gain_doc
from fd_monitor.model.system import load_system, parse_system

# QB paper Sec. VI, as printed.
P_PAPER = np.array([[94.1508, 0, -20.9304, 0], [0, 94.1508, 0, -20.9304],
                    [-20.9304, 0, 40.5391, 0], [0, -20.9304, 0, 40.5391]])
ALPHA_PAPER = np.array([0.0404, 0.0404, 0.2026, 0.2026])
BETA_PAPER = 0.486
L1_PAPER = np.array([[3.6486, 0], [0, 3.6486], [2.1926, 0], [0, 2.1926]])
L2_PAPER = np.array([[2.7647, 0], [0, 4.4939], [1.74, 0], [0, 2.1946]])
L3_PAPER = np.array([[4.4939, 0], [0, 2.7647], [2.1946, 0], [0, 1.74]])


@pytest.fixture(scope="module")
def pwa():
    return load_system("pwa_cascade")


@pytest.fixture(scope="module")
def design_paper(pwa):
    return design_qb(pwa, BETA_PAPER)


@pytest.fixture(scope="module")
def design_free(pwa):
    return design_qb(pwa)


def _max_eig(M: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(M)[-1])


def test_sec6_P_alpha_rho_at_published_beta(design_paper):
    """Sec. VI at beta = 0.486: P within 1e-3 relative, alpha within 1e-3, rho_max (eq. 6)."""
    d = design_paper
    rel = np.linalg.norm(d.P - P_PAPER) / np.linalg.norm(P_PAPER)
    assert rel < 1e-3, d.P
    assert np.max(np.abs(d.alpha - ALPHA_PAPER)) < 1e-3, d.alpha
    assert abs(d.rho_max - 0.1732) <= 5e-4
    assert d.rho_max == pytest.approx(1 / np.sqrt(np.linalg.eigvalsh(d.P)[0]))


def test_sec6_beta_free_is_at_least_as_good(design_free, design_paper):
    """The 1-D search over beta minimises rho_max: <= 0.1733 and <= the beta = 0.486 value."""
    assert design_free.rho_max <= 0.1733
    assert design_free.rho_max <= design_paper.rho_max + 1e-6
    assert design_free.beta != pytest.approx(BETA_PAPER, abs=1e-3)


def _min_max_eig_in_box(model, i, L0, tol):
    """min over |dL_jk| <= tol of lambda_max of (14a) for mode i at L0 + dL (the printed
    gains are rounded to 4 decimals; a violation that survives every rounding is real)."""
    import cvxpy as cp

    dL = cp.Variable(L0.shape)
    A, C, D, E = model.A[i], model.C[i], model.D[i], model.E[i]
    Y = P_PAPER @ (L0 + dL)
    PA, PG = P_PAPER @ A - Y @ C, P_PAPER @ D - Y @ E
    M = cp.bmat([[PA.T + PA + BETA_PAPER * P_PAPER, PG], [PG.T, -np.diag(ALPHA_PAPER)]])
    prob = cp.Problem(cp.Minimize(cp.lambda_max((M + M.T) / 2)), [cp.abs(dL) <= tol])
    prob.solve(solver=cp.CLARABEL)
    assert prob.status == cp.OPTIMAL
    return float(prob.value)


def test_sec6_published_gains_swapped_labels(pwa):
    """(14a) at the published P, alpha, beta: printed L_2, L_3 satisfy it for A_3, A_2
    (labels swapped in the text) up to the printed rounding; printed L_1 violates it for A_1
    whatever the rounding of its digits."""
    model = qb_model(pwa)
    # modes in the plant file: safe (A_1), x2_high (A_2), x1_high (A_3)
    blocks = lmi_blocks(model, P_PAPER, np.array([L1_PAPER, L3_PAPER, L2_PAPER]),
                        ALPHA_PAPER, BETA_PAPER)
    scale = max(np.linalg.norm(b, 2) for b in blocks)  # ~8e2
    # P and alpha are printed to 4 decimals and sum(alpha) = beta exactly: the optimum sits on
    # the LMI's boundary, so "satisfied" means max eigenvalue <= 1e-9 relative.
    assert _max_eig(blocks[1]) <= 1e-9 * scale  # printed L_3 with A_2
    assert _max_eig(blocks[2]) <= 1e-9 * scale  # printed L_2 with A_3
    as_printed = lmi_blocks(model, P_PAPER, np.array([L1_PAPER, L2_PAPER, L3_PAPER]),
                            ALPHA_PAPER, BETA_PAPER)
    assert _max_eig(as_printed[1]) > 1e-5 * scale  # labels as printed: violated
    assert _max_eig(as_printed[2]) > 1e-5 * scale
    # L_1: still violated by > 5e-3 for every gain within +-5e-4 of the printed digits
    assert _min_max_eig_in_box(model, 0, L1_PAPER, 5e-4) > 5e-3
    assert _min_max_eig_in_box(model, 1, L3_PAPER, 5e-4) <= 1e-9 * scale


def test_design_verified_and_tighter_bounds(design_free):
    d = design_free
    assert all(e < 0 for e in d.lmi_max_eig)
    assert all(a < 0 for a in d.spectral_abscissa)
    assert d.alpha.sum() <= d.beta
    comp = d.bounds["component_bound"]
    assert np.all(comp <= d.rho_max * (1 + 1e-12))  # sqrt((P^-1)_jj) <= 1/sqrt(lambda_min)
    model = d.model
    for i in range(model.s):
        # per-output bound <= r_max (eq. 11)
        assert np.all(d.bounds["output_bound"][i] <= d.bounds["r_max"][i] + 1e-12)


def test_min_norm_tie_break_is_reproducible(pwa, design_paper):
    """Tie-break: two designs give the same gains (the printed stop test compared non-unique
    gains)."""
    again = design_qb(pwa, BETA_PAPER)
    assert np.allclose(again.L, design_paper.L, rtol=1e-4, atol=1e-6)


def test_min_norm_tie_break_succeeds_on_sec6(design_paper, design_free, repo):
    """Step 4 returns optimal on pwa_cascade (no fallback to the step-5 gains), also in the
    shipped gain file."""
    assert design_paper.solver["tie_break"].startswith("minimum-norm (inner margin")
    assert design_free.solver["tie_break"].startswith("minimum-norm (inner margin")
    doc = yaml.safe_load((repo / "config" / "gains" / "pwa_cascade_qb.yaml").read_text())
    assert doc["solver"]["tie_break"].startswith("minimum-norm (inner margin")


def test_min_norm_gains_no_larger_than_step5(pwa, design_paper):
    """The step-5 gains at the same P are feasible for the tie-break (their margin is 10x
    larger), so the minimum-norm |(P L_i)_i|_F is at most theirs; P is step 5's."""
    from fd_monitor.design.qb import QBProblem

    prob = QBProblem(qb_model(pwa), 10 * 1e-6)
    _, status = prob.solve(BETA_PAPER)
    assert status == "optimal"
    P5 = 0.5 * (prob.P.value + prob.P.value.T)
    assert np.allclose(design_paper.P, P5, rtol=1e-9, atol=1e-9)
    y5 = np.sqrt(sum(np.linalg.norm(Y.value) ** 2 for Y in prob.Y))
    y_tb = np.sqrt(sum(np.linalg.norm(design_paper.P @ L) ** 2 for L in design_paper.L))
    assert y_tb <= y5 * (1 + 1e-6)


def test_reduced_lmis_same_optimum(pwa):
    """Eliminating Y_i (projection lemma) leaves lambda*(beta) unchanged (the search uses it)."""
    from fd_monitor.design.qb import QBProblem

    model = qb_model(pwa)
    for b in (0.1, BETA_PAPER, 2.0):
        full, _ = QBProblem(model).solve(b)
        red, _ = QBProblem(model, reduced=True).solve(b)
        assert red == pytest.approx(full, rel=1e-5), b


def test_gain_file_roundtrip_and_tamper(tmp_path, pwa, design_paper):
    path = write_gain_file(tmp_path / "g.yaml", pwa, design_paper, ("b1", "b2"), {})
    gf = load_gains(path, pwa)
    assert gf.certificate_status == "verified"
    assert gf.results["rho_max"] == pytest.approx(design_paper.rho_max)
    doc = yaml.safe_load(path.read_text())
    doc["results"]["rho_max"] = 0.05  # a tighter threshold than P guarantees
    bad = tmp_path / "bad.yaml"
    write_gain_doc(bad, doc)  # re-digested: the recomputed bound refuses it
    with pytest.raises(GainFileError, match="rho_max"):
        load_gains(bad, pwa)
    doc = yaml.safe_load(path.read_text())
    doc["results"]["L"]["safe"] = [[0.0, 0.0]] * 4  # no output injection: A - L C not Hurwitz
    write_gain_doc(bad, doc)
    with pytest.raises(GainFileError, match="safe"):
        load_gains(bad, pwa)


def test_gain_file_for_another_plant_refused(repo):
    other = load_system("three_tank")
    with pytest.raises(GainFileError, match="another plant"):
        load_gains(repo / "config" / "gains" / "pwa_cascade_qb.yaml", other)


def test_shipped_gain_file_verifies(pwa, repo):
    gf = load_gains(repo / "config" / "gains" / "pwa_cascade_qb.yaml", pwa)
    assert gf.certificate_status == "verified"
    assert gf.results["beta"] == pytest.approx(BETA_PAPER)
    assert abs(gf.results["rho_max"] - 0.1732) <= 5e-4
    check_certificate(pwa, gf)


# --------------------------------------------------------------------------------------
# properties and errors on small plants


def _lti(A, C, D, E, time="continuous", name="lti", extra_modes=None):
    n, ny, nw = A.shape[0], C.shape[0], D.shape[1]
    modes = {"m0": {"A": A.tolist(), "C": C.tolist(), "D": D.tolist(), "E": E.tolist()}}
    for k, A2 in enumerate(extra_modes or []):
        modes[f"m{k + 1}"] = {"A": A2[0].tolist(), "C": A2[1].tolist(), "D": D.tolist(),
                              "E": E.tolist()}
    data = {"format_version": 1, "name": name, "time": time, "sample_time": 0.01,
            "states": [f"x{i}" for i in range(n)], "outputs": [f"y{i}" for i in range(ny)],
            "disturbances": [f"w{i}" for i in range(nw)],
            "bounds": {"disturbance": [1.0] * nw}, "modes": modes,
            "initial": {"mode": "m0", "state": [0.0] * n}}
    return parse_system(data, "<test>")


def _random_detectable(rng, n, ny, nw, time):
    while True:
        A = rng.normal(size=(n, n))
        if time == "discrete":
            A = A / max(1e-9, np.abs(np.linalg.eigvals(A)).max()) * rng.uniform(0.5, 1.3)
        C = rng.normal(size=(ny, n))
        if not unobservable_unstable(A, C, time):
            return A, C, 0.1 * rng.normal(size=(n, nw)), 0.01 * rng.normal(size=(ny, nw))


@pytest.mark.parametrize("time", ["continuous", "discrete"])
def test_random_detectable_lti_property(time):
    """Theorem 1 (and its discrete counterpart): seeded random detectable LTI plants give L
    with A - L C Hurwitz (Schur) and a certificate that holds."""
    rng = np.random.default_rng(20261122)
    for trial in range(6):
        n = int(rng.integers(2, 6))
        ny = int(rng.integers(1, n))
        # nw = n disturbances with ny < n outputs: L E = D has no solution, so the error
        # cannot be made zero (that would make max lambda_min(P) unbounded).
        A, C, D, E = _random_detectable(rng, n, ny, n, time)
        sys_ = _lti(A, C, D, E, time=time, name=f"rnd{trial}")
        d = design_qb(sys_)
        a = spectral_abscissa(A - d.L[0] @ C, time)
        assert (a < 0) if time == "continuous" else (a < 1), (trial, a)
        check_certificate(sys_, SimpleNamespace(
            results={"time": time, "P": d.P, "L": {"m0": d.L[0]}, "alpha": d.alpha,
                     "beta": d.beta, **{k: d.bounds[k] for k in
                                        ("rho_max", "component_bound", "r_max", "output_bound")}},
            certificate={"lmi_max_eig": d.lmi_max_eig,
                         "spectral_abscissa": d.spectral_abscissa}))
        if time == "discrete":
            assert 0 < d.beta < 1
        assert d.solver["tie_break"].startswith("minimum-norm"), d.solver["tie_break"]


def test_not_detectable_mode_is_named():
    A = np.array([[0.0, 0.0], [0.0, 1.0]])  # eigenvalue 1 unobservable from C
    C = np.array([[1.0, 0.0]])
    good = (np.array([[-1.0, 1.0], [0.0, -1.0]]), np.array([[1.0, 0.0]]))
    sys_ = _lti(good[0], good[1], np.zeros((2, 1)), np.zeros((1, 1)),
                extra_modes=[(A, C)])
    with pytest.raises(DesignError, match=r"mode 'm1'.*not detectable"):
        design_qb(sys_)


def test_infeasible_lmi_is_reported():
    """Both modes observable, but (14a) asks p12 + p22 < 0 (mode 0) and p11 + p12 < 0
    (mode 1), i.e. [1 1] P [1 1]' < 0: no common P > 0."""
    A0, C0 = np.array([[0.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    A1, C1 = np.array([[1.0, 0.0], [1.0, 0.0]]), np.array([[0.0, 1.0]])
    sys_ = _lti(A0, C0, 0.1 * np.eye(2), np.zeros((1, 2)), extra_modes=[(A1, C1)])
    with pytest.raises(DesignError, match="infeasible"):
        design_qb(sys_)


def test_solver_failure_is_reported(monkeypatch, pwa):
    from fd_monitor.design import qb as dq

    monkeypatch.setattr(dq.QBProblem, "solve", lambda self, b, **kw: (float("nan"), "solver_error"))
    with pytest.raises(DesignError, match=r"solver CLARABEL failed.*try"):
        design_qb(pwa)


def test_bad_beta_rejected(pwa):
    with pytest.raises(DesignError, match="--beta"):
        design_qb(pwa, -1.0)


def test_cli_one_line_errors(tmp_path: Path, python, repo):
    A, C = np.array([[0.0, 0.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    data = {"format_version": 1, "name": "nd", "time": "continuous", "sample_time": 0.01,
            "states": ["a", "b"], "outputs": ["y"],
            "modes": {"only": {"A": A.tolist(), "C": C.tolist()}},
            "initial": {"mode": "only", "state": [0.0, 0.0]}}
    f = tmp_path / "nd.yaml"
    f.write_text(yaml.safe_dump(data))
    out = subprocess.run([python, "-m", "fd_monitor", "design", "qb", str(f), "-o",
                          str(tmp_path / "g.yaml")], capture_output=True, text=True, cwd=repo)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "mode 'only'" in out.stderr
    assert "Traceback" not in out.stderr


def test_cli_design_writes_verified_file(tmp_path: Path, python, repo):
    g = tmp_path / "g.yaml"
    out = subprocess.run([python, "-m", "fd_monitor", "design", "qb", "pwa_cascade", "-o",
                          str(g), "--beta", "0.486", "--json"], capture_output=True, text=True,
                         cwd=repo)
    assert out.returncode == 0, out.stderr
    import json

    doc = json.loads(out.stdout)
    assert abs(doc["rho_max"] - 0.1732) <= 5e-4
    assert load_gains(g, load_system("pwa_cascade")).certificate_status == "verified"
