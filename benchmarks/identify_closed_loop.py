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
   intervals contain the true eigenvalues (iv and ls).
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

from fd_monitor.analysis.identify import identify  # noqa: E402


def _identify(*argv: str) -> tuple[int, dict, str]:
    p = subprocess.run([sys.executable, "-m", "fd_monitor", "identify", *argv, "--json"],
                       capture_output=True, text=True, cwd=REPO)
    return p.returncode, json.loads(p.stdout) if p.returncode == 0 else {}, p.stderr


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    out = Path(a.out or tempfile.mkdtemp(prefix="identify_cl_"))
    out.mkdir(parents=True, exist_ok=True)
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
            se = np.asarray(q["coefficients"][0]["se_B"])
            print(f"  chosen {s['model']}/{s['estimator']}; sim fit % "
                  f"{np.round(q['simulation']['fit_percent'], 1).tolist()}; "
                  f"B[w2,tau2] = {B[1, 1]:.4g} +- {se[1, 1]:.2g} (true {B_TRUE[1, 1]:g}, "
                  f"error {100 * (B[1, 1] / B_TRUE[1, 1] - 1):+.1f} %)")
            for e in q["excitation"]:
                print(f"  {e['input']}: own {100 * e['own_share']:.3g} %, gain se "
                      f"{100 * e['gain_rel_se']:.3g} %, {'WEAK' if e['weak'] else 'ok'}")
            if not extra:
                for c in s["candidates"]:
                    print(f"    {c['model']}/{c['estimator']}: sim fit % "
                          f"{np.round(c['simulation_fit'], 1).tolist()}"
                          + (" *" if c["chosen"] else ""))
    true = np.linalg.eigvals(A_TRUE)
    for est in ("iv", "ls"):
        hits = 0
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
        print(f"\neigenvalue intervals ({est}) contain the true {np.round(true, 4).tolist()} "
              f"in {hits} of {a.seeds} seeds")
    print(f"\nbags and plant files in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
