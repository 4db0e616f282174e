"""A two-input plant in closed loop, one input excited only through feedback (issue 20).

    .venv/bin/python benchmarks/identify_closed_loop.py [--seeds 10] [--out DIR]

The plant and controller of ``test/test_identify_quality.py`` (two coupled velocities, tau1 a
PI loop tracking set points, tau2 = -2 w2 a P loop holding w2 at zero), 30 s fit and 10 s
held-out bags at 100 Hz:

1. no dither: ``identify --model linear --estimator iv`` (warning expected on tau2), then the
   same with ``--strict`` (refused, exit 2), then ``--model auto``;
2. a dither on tau2 (uniform +-0.3 N m, held 2 samples): the same commands; the tau2 -> w2
   gain against the true 0.06;
3. ``--seeds`` seeds of the dithered plant: how often the stated joint 95 % eigenvalue
   intervals contain the true eigenvalues (iv and ls), and the stated standard error of the
   eigenvalues' real part against the spread of the estimates;
4. the same comparison on a numpy simulation of the dc_motor example (J dw/dt = tau - b w -
   Fc, zero-order hold, its PI loop and noise; 2 x 60 s fit, 60 s held out, 20 seeds): where
   the measurement noise dominates and A is near 1 the standard errors are conservative;
5. the issue's case, smaller: two coupled pendulum joints (positions and velocities measured)
   under PD control with gravity compensation, joint 1 tracking set points, joint 2 held
   (60 s x 2 fit, 60 s held out), without and with a white +-0.3 N m dither on tau2:
   ``identify(..., model/estimator auto)``, the tau2 -> qd2 gain against Ts / J2 = 0.2.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "test"))
from test_identify_quality import A_TRUE, B_TRUE, FAST, bag, dataset  # noqa: E402

from fd_monitor.analysis.identify import Dataset, identify  # noqa: E402


def _identify(*argv: str) -> tuple[int, dict, str]:
    p = subprocess.run([sys.executable, "-m", "fd_monitor", "identify", *argv, "--json"],
                       capture_output=True, text=True, cwd=REPO)
    return p.returncode, json.loads(p.stdout) if p.returncode == 0 else {}, p.stderr


def _motor(seed: int, K: int = 6000) -> Dataset:
    """The dc_motor example in numpy: J = 0.02, b = 0.04, Fc = 0.15, Ts = 0.01, its PI loop
    (kp 0.1, ki 0.5, effort 0.17..1) on set points 1-6 rad/s every 5 s, velocity noise
    uniform +-0.01, uncertainty +-2e-4 per sample."""
    J, b, Fc, Ts = 0.02, 0.04, 0.15, 0.01
    a = np.exp(-b * Ts / J)
    beta = (1 - a) / b
    rng = np.random.default_rng(seed)
    r = np.repeat(rng.uniform(1, 6, K // 500 + 1), 500)[:K]
    w, integ = 2.0, 0.0
    U, Y = np.empty((K, 1)), np.empty((K, 1))
    for k in range(K):
        y = w + rng.uniform(-0.01, 0.01)
        e = r[k] - y
        integ += 0.5 * Ts * e
        U[k, 0], Y[k, 0] = min(max(0.1 * e + integ, 0.17), 1.0), y
        w = a * w + beta * U[k, 0] - beta * Fc + rng.uniform(-2e-4, 2e-4)
    return Dataset(f"motor{seed}", ("effort",), ("velocity",), np.arange(K), U, Y, Ts)


def _arm(seed: int, K: int = 6000, dither: float = 0.0) -> Dataset:
    """Two pendulum joints (J 0.1, 0.05; b 0.2, 0.1; m g l 2, 1; coupling spring 0.3),
    PD (8, 1) + gravity compensation on the measured angles, noise 2e-3 rad, 2e-2 rad/s."""
    Ts, J, b = 0.01, np.array([0.1, 0.05]), np.array([0.2, 0.1])
    mgl, kc = np.array([2.0, 1.0]), 0.3
    rng = np.random.default_rng(seed)
    r1 = np.repeat(rng.uniform(-0.8, 0.8, K // 300 + 1), 300)[:K]
    q, qd = np.array([0.0, 0.3]), np.zeros(2)
    U, Y = np.empty((K, 2)), np.empty((K, 4))
    for k in range(K):
        y = np.r_[q + rng.normal(0, 2e-3, 2), qd + rng.normal(0, 2e-2, 2)]
        tau = 8.0 * (np.array([r1[k], 0.3]) - y[:2]) - y[2:] + mgl * np.sin(y[:2])
        tau[1] += dither * rng.uniform(-1, 1)
        U[k], Y[k] = tau, y
        for _ in range(10):                     # the arm between samples, 1 ms steps
            acc = (tau - b * qd - mgl * np.sin(q) - kc * (q - q[::-1])) / J
            qd = qd + acc * Ts / 10
            q = q + qd * Ts / 10
    return Dataset(f"arm{seed}", ("tau1", "tau2"), ("q1", "q2", "qd1", "qd2"), np.arange(K),
                   U, Y, Ts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    out = Path(a.out or tempfile.mkdtemp(prefix="identify_cl_"))
    out.mkdir(parents=True, exist_ok=True)
    if any(out.iterdir()):
        print(f"{out}: not empty (bags are never overwritten): give a new --out")
        return 2
    for dither in (0.0, 0.3):
        tag = "dither" if dither else "no_dither"
        fit = bag(out / f"{tag}_fit", 1, 3000, dither)
        held = bag(out / f"{tag}_held", 2, 1000, dither)
        base = [str(fit), "--holdout", str(held), "--max-window", "0.3", "--force"]
        for extra in (["--model", "linear", "--estimator", "iv"],
                      ["--model", "linear", "--estimator", "iv", "--strict"], []):
            rc, s, err = _identify(*base, *extra, "-o", str(out / f"{tag}.yaml"))
            print(f"\n== {tag}: identify {' '.join(extra) or '(auto)'}: exit {rc}")
            for ln in err.splitlines():
                if ln.startswith(("WARNING", "fd_monitor: error")):
                    print("  " + ln[:300] + ("..." if len(ln) > 300 else ""))
            if not s:
                continue
            q = s["quality"]
            B = np.asarray(q["coefficients"][0]["B"])
            se = q["coefficients"][0]["se_B"][1][1]          # null (JSON): undetermined
            print(f"  chosen {s['model']}/{s['estimator']}; sim fit % "
                  f"{np.round(q['simulation']['fit_percent'], 1).tolist()}; "
                  f"B[w2,tau2] = {B[1, 1]:.4g} +- {'inf' if se is None else f'{se:.2g}'} "
                  f"(true {B_TRUE[1, 1]:g}, error {100 * (B[1, 1] / B_TRUE[1, 1] - 1):+.1f} %)")
            for e in q["excitation"]:
                g = e["gain_rel_se"]
                print(f"  {e['input']}: own {100 * e['own_share']:.3g} %, gain se "
                      f"{'inf' if g is None else f'{100 * g:.3g}'} %, "
                      f"{'WEAK' if e['weak'] else 'ok'}")
            if not extra:
                for c in s["candidates"]:
                    print(f"    {c['model']}/{c['estimator']}: sim fit % "
                          f"{np.round(c['simulation_fit'], 1).tolist()}"
                          + (" *" if c["chosen"] else ""))
    true = np.linalg.eigvals(A_TRUE)
    for est in ("iv", "ls"):
        hits, ses, errs = 0, [], []
        for seed in range(a.seeds):
            res = identify([dataset(100 + seed, 2000, 0.3)], [dataset(200 + seed, 400, 0.3)],
                           name="cl", model="linear", estimator=est, **FAST)
            eig = res.summary["quality"]["coefficients"][0]["eigenvalues"]
            ok = True
            for lam in true:
                e = min(eig, key=lambda e: abs(complex(e["real"], e["imag"]) - lam))
                ok &= bool(e["interval_real"][0] <= lam.real <= e["interval_real"][1]
                           and e["interval_imag"][0] <= lam.imag <= e["interval_imag"][1])
            hits += ok
            e0 = max(eig, key=lambda e: e["imag"])
            ses.append(e0["se_real"])
            errs.append(e0["real"] - true[0].real)
        print(f"\neigenvalue intervals ({est}) contain the true {np.round(true, 4).tolist()} "
              f"in {hits} of {a.seeds} seeds")
        print(f"  {est}: mean stated se of Re(lambda) {np.mean(ses):.3g}, RMS error of "
              f"Re(lambda) {np.sqrt(np.mean(np.square(errs))):.3g}")
    est_m, se_m = [], []
    for seed in range(20):
        res = identify([_motor(seed), _motor(100 + seed)], [_motor(200 + seed)], name="m",
                       model="affine", estimator="iv", max_window=0.2)
        co = res.summary["quality"]["coefficients"][0]
        est_m.append([co["A"][0][0], co["B"][0][0]])
        se_m.append([co["se_A"][0][0], co["se_B"][0][0]])
    sd, se = np.std(est_m, axis=0, ddof=1), np.mean(se_m, axis=0)
    print(f"\ndc_motor (20 seeds): a: stated se {se[0]:.3g}, spread {sd[0]:.3g} "
          f"({se[0] / sd[0]:.2g} x); beta: stated se {se[1]:.3g}, spread {sd[1]:.3g} "
          f"({se[1] / sd[1]:.2g} x)")
    for dither in (0.0, 0.3):
        res = identify([_arm(1, dither=dither), _arm(2, dither=dither)],
                       [_arm(3, dither=dither)], name="arm", max_window=0.5)
        s = res.summary
        print(f"\narm, dither {dither}: chosen {s['model']}/{s['estimator']}; "
              f"B[qd2,tau2] = {res.models[0].B[3, 1]:.4g} (Ts / J2 = 0.2), "
              f"B[qd1,tau1] = {res.models[0].B[2, 0]:.4g} (0.1)")
        for e in s["quality"]["excitation"]:
            print(f"  {e['input']}: own {100 * e['own_share']:.3g} %, gain se "
                  f"{100 * e['gain_rel_se']:.3g} %, {'WEAK' if e['weak'] else 'ok'}")
        for n in s["quality"]["noise_check"]:
            print(f"  noise {n['output']}: bound {n['bound']:.3g}, hf std {n['hf_std']:.3g}"
                  f"{'' if n['ok'] else ' BELOW'}")
        for w in s["warnings"]:
            print("  WARNING: " + w[:160] + "...")
        if dither:
            iv = identify([_arm(1, dither=dither), _arm(2, dither=dither)],
                          [_arm(3, dither=dither)], name="arm", max_window=0.5,
                          model="affine", estimator="iv")
            co = iv.summary["quality"]["coefficients"][0]
            print(f"  --estimator iv alone (a white dither is invisible to its instrument): "
                  f"B[qd2,tau2] = {co['B'][3][1]:.3g} +- {co['se_B'][3][1]:.2g}")
    print(f"\nbags and plant files in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
