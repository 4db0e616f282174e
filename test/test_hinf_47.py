"""Thesis (Armeni) Sec. 4.7 reproduction and the hinf_sc designer's contracts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("cvxpy")

from fd_monitor.core.hinf_certificate import check_certificate
from fd_monitor.core.methods import load_gains
from fd_monitor.core.residual_bank import ResidualBank
from fd_monitor.core.simulator import simulate
from fd_monitor.design import hinf_sc, hinf_spec
from fd_monitor.design._lmi_common import load_design_section
from fd_monitor.model.errors import DesignError, GainFileError
from fd_monitor.model.gains import save_gains, write_gain_doc
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system, parse_system

A = np.array([[-0.8, 0, 0], [0, -0.5, 0.6], [0, -0.6, -0.5]])
C = np.array([[1.0, 1, 0], [0, 1, 1]])
F = [np.array([1.0, 1, 0]), np.array([1.0, 0, 1])]


@pytest.fixture(scope="module")
def system():
    return load_system("thesis_4_7")


@pytest.fixture(scope="module")
def bank(system):
    sec, origin, sha = load_design_section(system, "hinf_sc")
    return hinf_sc.design(system, sec, origin, sha)


def test_projection_matrices_eq_4_69(bank):
    H1, H2 = (np.asarray(g["H"]) for g in bank["results"]["generators"])
    np.testing.assert_allclose(H1, [[0.5, -0.5], [-0.5, 0.5]], atol=1e-12)
    np.testing.assert_allclose(H2, [[0.2, -0.4], [-0.4, 0.8]], atol=1e-12)


def test_mu_grid_4_70(bank):
    for i, g in enumerate(bank["results"]["generators"]):
        grid = np.asarray(g["mu_grid"]["lambda"])
        mu = np.asarray(g["mu_grid"]["mu"])
        assert grid.size == 50 and grid[0] == -10.0 and grid[-1] == pytest.approx(-0.1)
        assert all(s == "optimal" for s in g["mu_grid"]["status"])
        assert np.all(np.isfinite(mu)) and np.all(mu > 0)
        # (4.70): mu = gamma^2 lambda^2 / ||H C F||^2 at the chosen lambda
        lam, g2 = g["lambda"], g["gamma2"]["nuisance"]
        HCF = np.asarray(g["H"]) @ C @ F[i]
        assert g["mu"] == pytest.approx(g2 * lam ** 2 / (HCF @ HCF), rel=1e-9)
        assert lam == grid[np.argmin(mu)]


@pytest.mark.parametrize("lam", [-0.5, -3.0, -10.0])
def test_fault_is_eigenvector_4_37(system, lam):
    sec, origin, sha = load_design_section(system, "hinf_sc")
    out = hinf_sc.design(system, dict(sec, **{"lambda": lam, "compare_pure": False}),
                         origin, sha)
    for i, g in enumerate(out["results"]["generators"]):
        L = np.asarray(g["L0"])
        np.testing.assert_allclose((A - L @ C) @ F[i], lam * F[i], atol=1e-9)
        assert np.linalg.eigvals(A - L @ C).real.max() < 0
        assert np.abs(np.linalg.eigvals(A - L @ C)).max() < 50.0  # pole region |z| < 50


def test_sensitivity_constraint_beats_pure_attenuation(bank):
    """Fig. 4.4: S_fi_ri(0) is larger for (4.47) than (4.24), at the same nuisance bound."""
    for i, row in enumerate(bank["summary"]):
        me, other = ("f1", "f2") if i == 0 else ("f2", "f1")
        sc_own, pure_own = row["dc_gain"][me], row["pure_dc_gain"][me]
        # (4.33): the SC zero-frequency gain is ||H C F_i||^2 / lambda^2 exactly
        HCF = np.asarray(bank["results"]["generators"][i]["H"]) @ C @ F[i]
        assert sc_own == pytest.approx(HCF @ HCF / row["lambda"] ** 2, rel=1e-9)
        # certified ratio S_fi_ri(0) / gamma^2 (gamma^2 bounds S_fj_ri(jw) for all w)
        cert_sc = 10 * np.log10(sc_own / row["gamma2"]["nuisance"])
        cert_pure = 10 * np.log10(pure_own / row["pure_gamma2"]["nuisance"])
        assert cert_sc > cert_pure + 20.0
        # the nuisance is rejected at zero frequency by both (far below the fault's gain)
        assert row["dc_gain"][other] < 1e-6 * sc_own


def test_gain_file_round_trip_and_tamper(system, bank, tmp_path):
    p = save_gains(tmp_path / "g.yaml", "hinf_sc", system, bank["parameters"],
                   bank["results"], bank["certificate"], bank["solver"])
    gf = load_gains(p, system)
    assert gf.certificate_status == "verified"
    doc = yaml.safe_load(p.read_text())
    doc["results"]["generators"][0]["L0"][0][0] += 5.0
    # a plain edit is refused by the digest, naming the key path ...
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(GainFileError, match=r"edited after design: results\.generators\[0\]\.L0"):
        load_gains(tmp_path / "bad.yaml", system)
    # ... and one re-sealed with a fresh digest still fails its certificate
    write_gain_doc(tmp_path / "resealed.yaml", doc)
    with pytest.raises(GainFileError, match=r"certificate does not hold"):
        load_gains(tmp_path / "resealed.yaml", system)
    with pytest.raises(GainFileError):
        check_certificate(system, doc["results"])


def test_bank_isolates_overlapping_faults(system, bank):
    sc = load_scenario("thesis_4_7_overlap")
    tr = simulate(sc)
    b = ResidualBank(system, bank["results"])
    r = b.run(tr.u[0], tr.y[0])
    al = r > b.thresholds
    t = tr.t
    assert not al[t < 20].any()                       # no false alarm
    assert al[(t > 25) & (t < 60), 0].all()           # f1 detected by r1 ...
    assert not al[(t > 20) & (t < 60), 1].any()       # ... and not by r2 (isolation)
    assert al[(t > 70), 1].all() and al[(t > 70), 0].all()


def _sys(A_, B_, C_, faults):
    return parse_system({"name": "t", "sample_time": 0.01, "states": ["a", "b", "c"],
                         "inputs": ["u1", "u2"], "outputs": [f"y{i}" for i in range(len(C_))],
                         "modes": {"m": {"A": A_, "B": B_, "C": C_}}, "faults": faults,
                         "initial": {"mode": "m", "state": [0, 0, 0]}})


def test_assumption_failures_are_named():
    Al, B = A.tolist(), [[1, 1], [1, 0], [0, 1]]
    # two faults with the same output direction
    s = _sys(Al, [[1, 2], [1, 2], [0, 0]], C.tolist(),
             [{"name": "a", "kind": "actuator", "input": "u1"},
              {"name": "b", "kind": "actuator", "input": "u2"}])
    with pytest.raises(DesignError, match=r"A-4\.3 "):
        hinf_sc.design(s, {})
    # A-4.4 (and ): a fault in the unobservable subspace of a diagonal plant
    s = _sys([[-1, 0, 0], [0, -2, 0], [0, 0, -3]], B, [[1, 0, 0], [0, 1, 0]],
             [{"name": "a", "kind": "process", "F": [0, 0, 1]}])
    with pytest.raises(DesignError, match=r"A-4\.4"):
        hinf_sc.design(s, {})
    s = _sys([[-1, 0, 0], [0, -2, 0], [0, 0, -3]], B, [[1, 0, 0], [0, 1, 0]],
             [{"name": "a", "kind": "process", "F": [1, 0, 0]}])
    with pytest.raises(DesignError, match=r"A-4\.1"):
        hinf_sc.design(s, {})
    # (4.57): a sensor fault needs F with C F = E; C of rank 1 with 2 outputs
    s = _sys(Al, B, [[1, 1, 0], [2, 2, 0]], [{"name": "s", "kind": "sensor_bias",
                                             "output": "y0"}])
    with pytest.raises(DesignError, match=r"\(4.57\)"):
        hinf_sc.design(s, {})


def test_infeasible_lmi_and_bad_keys(system):
    sec = {"lambda": -1.0, "region": [{"kind": "halfplane", "alpha": 20.0}]}
    with pytest.raises(DesignError, match=r"infeasible at every lambda"):
        hinf_sc.design(system, sec, "x.design.yaml")
    with pytest.raises(DesignError, match=r"x.design.yaml: hinf_sc.weights.a: expected a "
                                          r"number > 0"):
        hinf_sc.design(system, {"weights": {"a": -1}}, "x.design.yaml")
    with pytest.raises(DesignError, match=r"hinf_sc.lambda_gird: expected one of the keys"):
        hinf_sc.design(system, {"lambda_gird": []}, "x.design.yaml")


def test_k_greater_than_zero():
    """C F = 0, C A F != 0: k = 1 (A-4.4, 4.31). Assigning (lambda, A F) then leaves
    w = F - A F / lambda with (A - L C) w = A F - A F = 0 for every L of (4.40): an
    eigenvalue 0, so (Abar, Cbar) is never detectable and A-4.3.5 is reported."""
    Al = [[-1, 1, 0], [0, -2, 1], [0, 0, -3]]
    s = _sys(Al, [[0, 0], [0, 0], [1, 0]], [[1, 0, 0], [0, 0, 1]],
             [{"name": "a", "kind": "process", "F": [0, 1, 0]}])
    spec = hinf_spec.parse_spec(s, {}, "<dict>", "")
    assert spec.faults[0].k == 1
    np.testing.assert_allclose(spec.faults[0].V[:, 0], [1, -2, 0])
    with pytest.raises(DesignError, match=r"A-4\.3\.5"):
        hinf_sc.design(s, {"lambda": -2.0})


def test_cli_json(tmp_path, repo):
    out = tmp_path / "g.yaml"
    res = subprocess.run([sys.executable, "-m", "fd_monitor", "design", "hinf_sc",
                          "thesis_4_7", "-o", str(out), "--json", "--lambda", "-1"],
                         capture_output=True, text=True, cwd=repo, timeout=120)
    assert res.returncode == 0, res.stderr
    import json

    doc = json.loads(res.stdout)
    assert doc["method"] == "hinf_sc" and doc["gain_file"] == str(out)
    assert [g["lambda"] for g in doc["generators"]] == [-1.0, -1.0]
    assert all("mu" in g for g in doc["generators"])
    res = subprocess.run([sys.executable, "-m", "fd_monitor", "design", "hinf_sc",
                          "thesis_4_7", "-o", str(out), "--force", "--grid", "-10", "-0.1",
                          "6"],
                         capture_output=True, text=True, cwd=repo, timeout=120)
    assert res.returncode == 0, res.stderr
    # The mu(lambda) table of eq. (4.35) over the grid, one column per generator.
    table = res.stdout.split("mu(lambda) over the lambda grid")[1].splitlines()[3:9]
    assert [float(r.split()[0]) for r in table] == pytest.approx(np.linspace(-10, -0.1, 6))
    assert all(float(v) > 0 for r in table for v in r.split()[1:3])
    res = subprocess.run([sys.executable, "-m", "fd_monitor", "design", "hinf_sc",
                          "thesis_4_7", "-o", str(out), "--force", "--lambda", "1"],
                         capture_output=True, text=True, cwd=repo, timeout=120)
    assert res.returncode == 2 and "--lambda: expected a finite number < 0" in res.stderr


def test_core_imports_no_cvxpy(repo):
    code = ("import sys, fd_monitor.core.residual_bank, fd_monitor.core.hinf_certificate, "
            "fd_monitor.core.freq, "
            "fd_monitor.core.generalized_observer; "
            "assert 'cvxpy' not in sys.modules and 'rclpy' not in sys.modules")
    res = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0, res.stderr


def test_shipped_gain_file_verifies(system):
    p = Path(__file__).resolve().parent.parent / "config" / "gains" / "thesis_4_7_hinf_sc.yaml"
    gf = load_gains(p, system)
    assert gf.certificate_status == "verified"
