"""How good is an identified model, and when should it not be trusted (issue 20).

Called by :func:`fd_monitor.analysis.identify.identify` on its one-step rows; the numerics are
:mod:`fd_monitor.core.identify`. Every ``identify`` run reports:

* **simulation fit** on held-out data, per output (NRMSE %, MATLAB's ``compare``): the model
  run free from each held-out record's first measurement with the measured inputs (and the
  measured mode labels), beside the one-step RMS (a one-step prediction always looks good);
* **standard errors** of every A and B entry (sandwich covariance of the least-squares / IV
  estimate with Newey-West lags: the one-step error of a measured state is correlated over a
  sample) and of the eigenvalues (first-order perturbation), with simultaneous 95 % intervals;
  the **condition number** of the regression (columns scaled);
* **excitation** per input and mode: how much of the input's variation is its own (not a
  linear function of the current and previous measurements, the other inputs and its own
  previous value: what a feedback controller produces), its order of persistent excitation,
  how far its own part stands above the noise the controller feeds back, whether it reacts
  to the output noise (closed loop), and what that does to its gain (relative standard
  error); a weakly excited input gets a warning naming it, what it means and what to do;
* **bounds**: which are measured (on how many samples, how many seconds per mode) and which
  assumed (``--noise-bound``), and a check of the noise bound against the standard deviation
  of the residuals' high-frequency part;
* **how much data**: the model fitted on each half of the fit data and compared;
* **physical parameters** where the structure allows (a joint's velocity, or position and
  velocity, driven by one torque: inertia, damping, stiffness, constant torque).

Why one module of ~630 lines: every quality figure an ``identify`` run reports (fit,
statistics, excitation, closed loop, noise, halves, N4SID, physical parameters), one short
function each.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from fd_monitor.core.identify import (
    AffineModel,
    IdentificationError,
    condition_number,
    design_matrix,
    eigen_intervals,
    hac_covariance,
    nrmse_fit,
    partial_coefficients,
    pe_order,
    physical_joint,
    physical_velocity,
    simulate,
    solve,
)


class _Rows(Protocol):
    """One-step rows (:class:`fd_monitor.analysis.identify._Rows`; a protocol here, so this
    module does not import the one that calls it)."""

    X: np.ndarray
    U: np.ndarray
    Xn: np.ndarray
    Xp: np.ndarray
    Up: np.ndarray
    lag: np.ndarray
    key: np.ndarray
    seg: np.ndarray
    k: np.ndarray
    ds: np.ndarray

    def take(self, sel: np.ndarray) -> Any: ...

    @property
    def size(self) -> int: ...

__all__ = [
    "GAIN_SE_MAX",
    "OWN_SHARE_MIN",
    "NOISE_FACTOR",
    "simulation",
    "coefficient_statistics",
    "excitation",
    "feedback_corr",
    "closed_loop",
    "noise_check",
    "halves",
    "n4sid_models",
    "physical_parameters",
]

#: An input's gain (its B column) is trusted when its relative standard error is below this.
GAIN_SE_MAX = 0.10
#: An input whose own variation (what feedback from the outputs cannot produce) is below this
#: fraction of its spread is excited only through feedback.
OWN_SHARE_MIN = 0.01
#: A stated noise bound below this times the noise's standard deviation sigma is flagged.
#: Noise within +-b has a standard deviation of at most b, and b / sqrt(3) = 0.58 b if
#: uniform (the usual reading of a bound): below sigma no noise fits the bound, and below
#: 1.5 sigma (0.87 of a uniform noise's bound, the slack for sigma's own estimation error)
#: it is smaller than the residuals show.
NOISE_FACTOR = 1.5
#: Newey-West lags of the coefficient covariance (the one-step error is MA(1) in the noise).
HAC_LAGS = 2
#: Level of the eigenvalue intervals (simultaneous over every eigenvalue).
LEVEL = 0.95


def _segments(R: _Rows) -> list[np.ndarray]:
    """Row indices of each run of consecutive samples."""
    if R.size == 0:
        return []
    brk = np.nonzero((np.diff(R.k) != 1) | (np.diff(R.seg) != 0))[0] + 1
    return [r for r in np.split(np.arange(R.size), brk)]


def _breaks(R: _Rows) -> np.ndarray:
    """(N,) bool: row k does not follow row k - 1 in time."""
    b = np.ones(R.size, dtype=bool)
    if R.size > 1:
        b[1:] = (np.diff(R.k) != 1) | (np.diff(R.seg) != 0)
    return b


def simulation(Ms: Sequence[AffineModel], R: _Rows, q: np.ndarray) -> dict[str, Any]:
    """Free-run simulation of every held-out record from its first measurement.

    Returns
    -------
    dict
        ``fit`` (ny,) percent (NRMSE, as MATLAB ``compare``), ``rms`` (ny,) of the simulation
        error, ``samples``, ``records``, and for the plot ``k`` (N,), ``measured``,
        ``simulated`` (N, ny) of the first record.
    """
    meas, sim, first = [], [], None
    for rows in _segments(R):
        if rows.size < 2:
            continue
        X = simulate(list(Ms), q[rows], R.U[rows], R.X[rows[0]])
        meas.append(R.Xn[rows])
        sim.append(X[1:])
        if first is None:
            first = {"k": R.k[rows] + 1, "measured": R.Xn[rows], "simulated": X[1:]}
    if not meas:
        n = R.X.shape[1]
        return {"fit": np.full(n, np.nan), "rms": np.full(n, np.nan), "samples": 0,
                "records": 0}
    Y, S = np.vstack(meas), np.vstack(sim)
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.sqrt(np.mean((Y - S) ** 2, axis=0))
    return {"fit": nrmse_fit(Y, S), "rms": np.where(np.isfinite(err), err, np.inf),
            "samples": int(Y.shape[0]), "records": len(meas), **(first or {})}


def _regression(R: _Rows, q: np.ndarray, n_modes: int, kind: str, iv: bool,
                inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                             np.ndarray]:
    """Regressors, targets, instruments and breaks of one fit (the rows the fit used)."""
    sel = R.lag if iv else np.ones(R.size, dtype=bool)
    offsets = kind != "linear"
    Rs = R.take(sel)
    Th = design_matrix(Rs.X, Rs.U, q[sel], n_modes, inputs=inputs, offsets=offsets)
    Z = design_matrix(Rs.Xp, Rs.Up, q[sel], n_modes, inputs=inputs, offsets=offsets) \
        if iv else None
    return Th, Rs.Xn, Z, _breaks(Rs)


def coefficient_statistics(R: _Rows, q: np.ndarray, n_modes: int, *, kind: str,
                           per_mode: str, estimator: str, inputs: np.ndarray,
                           mode_names: Sequence[str],
                           at: Sequence[AffineModel] | None = None) -> list[dict[str, Any]]:
    """Standard errors of A and B, eigenvalue intervals and the condition number.

    The statistics are those of the unconstrained regression of the chosen kind (``sparse``:
    of its affine library, before terms are dropped; a clipped radius: before clipping), fitted
    with the chosen estimator. ``at``: a one-mode model that is not a regression's (n4sid):
    the least-squares sandwich evaluated at its coefficients and its residuals (n4sid has no
    covariance of its own; this is the spread the same rows give a regression estimate).

    Returns
    -------
    list of dict
        One per group (``all`` for shared A, B; one per mode for ``full``): ``mode``, ``A``,
        ``B``, ``se_A`` (n, n), ``se_B`` (n, nu), ``cov_A`` (n n, n n), ``eig`` (see
        :func:`fd_monitor.core.identify.eigen_intervals`), ``condition``, ``rank`` (of
        ``columns`` regressors), ``samples``.
    """
    n, nu = R.X.shape[1], R.U.shape[1]
    iv = estimator == "iv"
    lib_kind = "affine" if kind == "sparse" or at is not None else kind
    groups = [("all" if n_modes > 1 else mode_names[0], np.ones(R.size, dtype=bool),
               q, n_modes)] if per_mode == "offset" else \
        [(mode_names[j], q == j, np.zeros(R.size, dtype=int), 1) for j in range(n_modes)]
    out = []
    for name, rows, qq, nm in groups:
        Rg = R.take(rows)
        Th, Y, Z, brk = _regression(Rg, qq[rows], nm, lib_kind, iv, inputs)
        if at is not None and len(at) == 1:
            Mx = at[0]
            Xi = np.vstack([Mx.A.T, Mx.B[:, inputs].T, Mx.offset[None, :]])
        else:
            Xi = solve(Th, Y, Z)
        E = Y - Th @ Xi
        p = Th.shape[1]
        cov = hac_covariance(Th, E, Z, breaks=brk, lags=HAC_LAGS)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0)).reshape(n, p)     # row j: output j
        A = Xi[:n].T
        B = np.zeros((n, nu))
        B[:, inputs] = Xi[n:n + inputs.size].T
        se_B = np.zeros((n, nu))
        se_B[:, inputs] = se[:, n:n + inputs.size]
        idx = np.array([r * p + c for r in range(n) for c in range(n)])
        cov_A = cov[np.ix_(idx, idx)]
        out.append({"mode": name, "A": A, "B": B, "se_A": se[:, :n], "se_B": se_B,
                    "cov_A": cov_A, "eig": eigen_intervals(A, cov_A, LEVEL),
                    "condition": condition_number(Th), "rank": _rank(Th),
                    "columns": int(Th.shape[1]), "samples": int(Th.shape[0])})
    return out


def _rank(Theta: np.ndarray) -> int:
    """Numerical rank of the regressors (columns scaled; singular values above 1e-9 of the
    largest, the level at which :func:`hac_covariance` calls a direction undetermined)."""
    norms = np.linalg.norm(Theta, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    G = (Theta.T @ Theta) / np.outer(norms, norms)
    ev = np.sqrt(np.maximum(np.linalg.eigvalsh(G), 0.0))
    return int(np.count_nonzero(ev > 1e-9 * ev.max())) if ev.size and ev.max() > 0 else 0


def _fastest_hz(As: Sequence[np.ndarray], Ts: float) -> float:
    """Frequency of the fastest mode of the models (Hz, at most Nyquist)."""
    f = 0.0
    for A in As:
        for lam in np.linalg.eigvals(A):
            if abs(lam) > 0:
                f = max(f, abs(complex(np.log(complex(lam)))) / (2 * math.pi * Ts))
    return min(f, 0.5 / Ts) if f > 0 else 0.5 / Ts


def excitation(Rf: _Rows, qf: np.ndarray, Re: _Rows, qe: np.ndarray, Ee: np.ndarray,
               stats: Sequence[dict[str, Any]], *, inputs: Sequence[str],
               fit_inputs: np.ndarray, mode_names: Sequence[str], per_mode: str,
               sigma: np.ndarray, Ts: float, As: Sequence[np.ndarray],
               loop: dict[str, Any]) -> tuple[list[dict[str, Any]], list[str]]:
    """Excitation of every fitted input, over all modes and per mode, and the warnings.

    Parameters
    ----------
    Rf, qf : fit rows and their modes.
    Re, qe, Ee : held-out rows, modes and one-step errors (N, ny) (closed-loop correlation).
    stats : list of dict
        :func:`coefficient_statistics` (the gain's standard error).
    sigma : numpy.ndarray
        (ny,) measurement-noise standard deviation (the noise band).
    loop : dict
        :func:`closed_loop` (the feedback correlation per input).

    Returns
    -------
    rows : list of dict
        ``input``, ``mode`` (``all`` or a mode name), ``samples``, ``spread`` (std, input
        units), ``own_share`` (std of its own part / std), ``pe_order`` (of its own part),
        ``above_noise_db`` (its own part over the noise the controller feeds back, dB),
        ``feedback_corr`` (:func:`feedback_corr`), ``gain_rel_se``,
        ``weak`` (bool), ``reason``.
    warnings : list of str
        One per weakly excited input (and mode, for ``full``): what, what it means, what to do.
    """
    n = Rf.X.shape[1]
    nu = Rf.U.shape[1]
    max_order = min(2 * n + 2, 10)
    lag = Rf.lag
    rows_out: list[dict[str, Any]] = []
    warnings: list[str] = []
    f_hz = _fastest_hz(As, Ts)
    modes = [("all", np.ones(Rf.size, dtype=bool))] if len(mode_names) > 1 else []
    modes += [(nm, qf == j) for j, nm in enumerate(mode_names)]
    for j in fit_inputs:
        j = int(j)
        other = [i for i in range(nu) if i != j]
        corr = loop["corr"].get(inputs[j], 0.0)
        for mname, m in modes:
            sel = m & lag
            N = int(sel.sum())
            u = Rf.U[sel, j]
            spread = float(np.std(u)) if N else 0.0
            judged = mname == "all" or len(mode_names) == 1 or per_mode == "full"
            if N < 3 * (2 * n + nu + 1) or spread == 0.0:
                why = "too few samples" if spread else "constant"
                row = {"input": inputs[j], "mode": mname, "samples": N, "spread": spread,
                       "own_share": 0.0, "pe_order": 0, "above_noise_db": -math.inf,
                       "feedback_corr": corr, "gain_rel_se": _gain_se(stats, mname, j, per_mode),
                       "weak": judged, "reason": why if judged else why + " (shared B)"}
                rows_out.append(row)
                if judged:
                    warnings.append(_advice(row, 0.0, N, Ts, f_hz))
                continue
            qs = qf[sel]
            ind = (qs[:, None] == np.unique(qs)[None, :]).astype(float)
            others = np.hstack([Rf.X[sel], Rf.Xp[sel], Rf.U[sel][:, other], Rf.Up[sel], ind])
            coef = partial_coefficients(u, others)
            own = u - others @ coef
            K = np.vstack([coef[:n], coef[n:2 * n]])        # feedback on y_k and y_{k-1}
            band = float(np.sqrt(np.sum((K ** 2) @ (sigma ** 2))))
            own_sd = float(np.std(own))
            above = math.inf if band == 0 else (
                20 * math.log10(own_sd / band) if own_sd > 0 else -math.inf)
            g = _gain_se(stats, mname, j, per_mode)
            share = own_sd / spread
            weak_share = share < OWN_SHARE_MIN
            weak_gain = g > GAIN_SE_MAX
            weak = judged and (weak_share or weak_gain)
            reason = ", ".join(r for r, w in (("feedback only", weak_share),
                                              ("gain uncertain", weak_gain)) if w) or "ok"
            row = {"input": inputs[j], "mode": mname, "samples": N, "spread": spread,
                   "own_share": share,
                   "pe_order": pe_order(own, max_order) if share > 1e-9 else 0,
                   "above_noise_db": above, "feedback_corr": corr, "gain_rel_se": g,
                   "weak": weak, "reason": reason if judged else reason + " (shared B)"}
            rows_out.append(row)
            if weak:
                warnings.append(_advice(row, own_sd, N, Ts, f_hz))
    return rows_out, warnings


def _next_pairs(R: _Rows, E: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e_k, u_k+1, [y_k, u_k, 1]) over the rows whose next sample is in the record."""
    nxt = np.zeros(R.size, dtype=bool)
    if R.size > 1:
        nxt[:-1] = (np.diff(R.k) == 1) & (np.diff(R.seg) == 0)
    sel = np.nonzero(nxt)[0]
    past = np.hstack([R.X[sel], R.U[sel], np.ones((sel.size, 1))])
    return E[sel], R.U[sel + 1], past


def feedback_corr(pairs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], j: int) -> float:
    """Largest partial ``|corr(e_i,k, u_j,k+1 | y_k, u_k)|`` over the outputs i: does input j
    react to the one-step error (the output noise) of the sample before, beyond what the
    previous measurement and input predict of it? Zero in open loop (up to ``1 / sqrt(N)``);
    a controller that reads the outputs makes it nonzero (Ljung 1999, Sec. 16.6: the
    residual-input cross-correlation at negative lags reveals feedback)."""
    E = np.vstack([p[0] for p in pairs])
    un = np.concatenate([p[1][:, j] for p in pairs])
    past = np.vstack([p[2] for p in pairs])
    if un.size < past.shape[1] + 3:
        return 0.0
    r = un - past @ partial_coefficients(un, past)
    corr = 0.0
    for i in range(E.shape[1]):
        e = E[:, i]
        if np.std(r) > 1e-12 * max(float(np.std(un)), 1e-300) and np.std(e) > 0:
            corr = max(corr, abs(float(np.corrcoef(e, r)[0, 1])))
    return corr


def closed_loop(Rs: Sequence[_Rows], Es: Sequence[np.ndarray], fit_inputs: np.ndarray,
                inputs: Sequence[str]) -> dict[str, Any]:
    """Which inputs react to the output noise (:func:`feedback_corr` over the rows ``Rs``
    with their one-step errors ``Es``, above ``3 / sqrt(N)``, the 3-sigma level of a
    correlation estimate of independent series)."""
    pairs = [_next_pairs(R, E) for R, E in zip(Rs, Es)]
    N = max(sum(p[0].shape[0] for p in pairs), 1)
    limit = 3.0 / math.sqrt(N)
    corr = {inputs[int(j)]: feedback_corr(pairs, int(j)) for j in fit_inputs}
    return {"corr": corr, "limit": limit, "samples": N,
            "inputs": [nm for nm, c in corr.items() if c > limit]}


def _gain_se(stats: Sequence[dict[str, Any]], mode: str, j: int, per_mode: str) -> float:
    """Relative standard error of input j's B column (its 2-norm)."""
    if per_mode == "full" and len(stats) > 1:
        if mode == "all":                  # every mode its own B: the least determined one
            return max(_gain_se([st], mode, j, "offset") for st in stats)
        stats = [next((s for s in stats if s["mode"] == mode), stats[0])]
    st = stats[0]
    b = float(np.linalg.norm(st["B"][:, j]))
    se = float(np.linalg.norm(st["se_B"][:, j]))
    if not math.isfinite(se):
        return math.inf
    return se / b if b > 0 else math.inf


def _advice(row: dict[str, Any], own_sd: float, N: int, Ts: float, f_hz: float) -> str:
    """The warning: which input, what it means, what to do (dither amplitude, spectrum, data)."""
    g = row["gain_rel_se"]
    target = GAIN_SE_MAX / 2
    # a dither adds to the input's own part; the gain's standard error falls as
    # 1 / (sqrt(N) std(own part)) (least squares), so halving it needs twice the own part or
    # four times the data. Ask for the larger of: the gain's standard error down to half the
    # limit, and an own part of 10 x the limit on the share (not resting on feedback alone).
    want = 10 * OWN_SHARE_MIN * row["spread"]
    if math.isfinite(g) and g > 0 and own_sd > 0:
        want = max(want, own_sd * g / target)
    dither = math.sqrt(max(want ** 2 - own_sd ** 2, 0.0))
    more = (g / target) ** 2 if math.isfinite(g) and g > target else 0.0
    spectrum = (f"random levels or a PRBS held 2-3 samples, its spectrum flat up to "
                f"{f_hz:.3g} Hz, the fastest mode; a dither that changes every sample is "
                f"invisible to the iv estimate, whose instrument is the previous sample")
    if math.isfinite(g) and g <= 10:
        todo = (f"add a dither to {row['input']} ({spectrum}) of at least {dither:.3g} RMS in "
                f"its units")
        if more > 1:
            todo += f", or record about {more:.0f} x more data ({more * N * Ts:.0f} s)"
    else:
        todo = (f"add a dither to {row['input']} ({spectrum}), starting at about "
                f"{dither:.3g} RMS in its units (10 % of its spread), and identify again: the "
                f"gain's standard error then falls in proportion to the dither; more data "
                f"of the same kind do not help")
    where = "" if row["mode"] == "all" else f" in mode {row['mode']}"
    if not math.isfinite(g) or g > 10:
        gtxt = "its gain is not determined at all"
    else:
        gtxt = f"its gain is determined to +-{100 * g:.2g} % (1 standard error)"
    if row["own_share"] < OWN_SHARE_MIN:
        gtxt += (" and rests only on the noise the loop circulates (a nonlinear controller "
                 "term, a saturation or coloured noise biases it, which no standard error "
                 "shows)")
    return (f"input {row['input']} is weakly excited{where}: {100 * row['own_share']:.2g} % "
            f"of its variation is its own (the rest follows the outputs through feedback), "
            f"{_db(row['above_noise_db'])} the noise the controller feeds back, and {gtxt}. "
            f"The model's B column for {row['input']}, and every design made from it, may be "
            f"badly wrong: {todo}")


def _db(x: float) -> str:
    if x == math.inf:
        return "with no noise fed back besides"
    if x == -math.inf or x < -99:
        return "none of it above"
    return f"{x:.3g} dB above" if x >= 0 else f"{-x:.3g} dB below"


def noise_check(v_bar: np.ndarray, sigma: np.ndarray, outputs: Sequence[str],
                assumed: bool) -> tuple[list[dict[str, Any]], list[str]]:
    """Flag a noise bound below ``NOISE_FACTOR`` x the residuals' high-frequency std."""
    rows, warns = [], []
    for i, o in enumerate(outputs):
        ok = bool(v_bar[i] >= NOISE_FACTOR * sigma[i])
        rows.append({"output": o, "bound": float(v_bar[i]), "hf_std": float(sigma[i]),
                     "ratio": float(v_bar[i] / sigma[i]) if sigma[i] > 0 else math.inf,
                     "ok": ok})
        if not ok:
            src = "the stated (--noise-bound)" if assumed else "the measured"
            warns.append(
                f"output {o}: {src} noise bound {v_bar[i]:.4g} is below {NOISE_FACTOR:.3g} x "
                f"the standard deviation {sigma[i]:.4g} of the one-step errors' "
                f"high-frequency part (white noise within +-b has a standard deviation of at "
                f"most b, b / sqrt(3) = 0.58 b if uniform): the noise is larger than the bound "
                f"says, and a design on it will raise false alarms ("
                + ("check the datasheet value against what the sensor sees installed "
                   "(quantisation, vibration, interference), or leave --noise-bound out to "
                   "measure it)" if assumed else
                   "state the sensor's datasheet bound with --noise-bound, or raise --margin)"))
    return rows, warns


def halves(fit: Callable[[np.ndarray], list[AffineModel]], Rf: _Rows,
           sim: Callable[[Sequence[AffineModel]], np.ndarray],
           stats: Callable[[np.ndarray], list[dict[str, Any]]],
           full_fit: np.ndarray, outputs: Sequence[str], inputs: Sequence[str]
           ) -> dict[str, Any]:
    """The model fitted on the first and on the second half of the fit rows, compared.

    Parameters
    ----------
    fit : callable
        Row mask (N,) bool -> the models fitted on those rows.
    sim : callable
        Models -> (ny,) held-out simulation fit (%).
    stats : callable
        Row mask -> :func:`coefficient_statistics` of those rows (their standard errors).
    full_fit : numpy.ndarray
        (ny,) the full data's simulation fit.
    outputs, inputs : sequence of str
        Channel names (to name the entry that differs most).

    Returns
    -------
    dict
        ``fit_first``, ``fit_second`` (ny,) %, ``max_z`` (largest difference of an A or B
        entry between the halves over its standard error), ``entry`` (where), ``z_critical``
        (Bonferroni 5 % over the entries), ``fit_difference`` (largest difference of the
        halves' simulation fits, points), ``stable`` (``max_z <= z_critical``), ``verdict``.
    """
    from scipy.stats import norm

    half = np.zeros(Rf.size, dtype=bool)
    half[: Rf.size // 2] = True
    out: dict[str, Any] = {}
    try:
        M1, M2 = fit(half), fit(~half)
        S1, S2 = stats(half), stats(~half)
    except (IdentificationError, np.linalg.LinAlgError, ValueError) as exc:
        return {"stable": False, "verdict": f"halves not fitted ({exc})"}
    f1, f2 = sim(M1), sim(M2)
    zmax, where, entries = 0.0, "", 0
    for a, b in zip(S1, S2):
        for key, se_key in (("A", "se_A"), ("B", "se_B")):
            d = np.abs(a[key] - b[key])
            s = np.sqrt(a[se_key] ** 2 + b[se_key] ** 2)
            used = s > 0
            entries += int(used.sum())
            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.where(used, d / np.where(used, s, 1.0), 0.0)
            if z.size and float(z.max()) > zmax:
                zmax = float(z.max())
                r, c = (int(i) for i in np.unravel_index(int(np.argmax(z)), z.shape))
                cols = outputs if key == "A" else inputs
                where = f"{key}[{outputs[r]},{cols[c]}]" + (
                    "" if a["mode"] == "all" or len(S1) == 1 else f" ({a['mode']})")
    zc = float(norm.ppf(1 - 0.05 / (2 * max(entries, 1))))
    dfit = float(np.max(np.abs(np.asarray(f1) - np.asarray(f2)))) \
        if np.all(np.isfinite(f1)) and np.all(np.isfinite(f2)) else math.inf
    # the verdict rests on the coefficients: a free-run simulation of a nearly integrating
    # plant amplifies a small difference of its slowest eigenvalue into a large one of fit
    stable = zmax <= zc
    out.update({"fit_first": np.asarray(f1), "fit_second": np.asarray(f2),
                "fit_full": np.asarray(full_fit), "max_z": zmax, "entry": where,
                "z_critical": zc, "fit_difference": dfit, "stable": stable})
    full = np.asarray(full_fit, dtype=float)
    spread = float(np.max(np.abs(np.concatenate([np.asarray(f1) - full,
                                                 np.asarray(f2) - full])))) \
        if np.all(np.isfinite(full)) else math.inf
    sim_note = "" if spread <= 10.0 else (
        f"; but the halves' free-run simulations differ from the full data's by up to "
        f"{spread:.3g} fit points (a slowest eigenvalue near 1 moves a long simulation far): "
        f"more data would still sharpen the simulation")
    out["verdict"] = (
        "the halves agree within their standard errors: more data of the same kind would not "
        "change the coefficients much" + sim_note if stable else
        f"the halves disagree ({where} differs by {zmax:.3g} standard errors, critical "
        f"{zc:.3g}): more data, or data with more excitation, would change the model")
    return out


def n4sid_models(Rf: _Rows, n_modes: int, *, inputs: np.ndarray, nu: int,
                 block_rows: int | None = None) -> list[AffineModel]:
    """A subspace (N4SID, ``nfoursid``) candidate in the measured-state coordinates.

    ``nfoursid`` fits ``x+ = A x + B u + K e``, ``y = C x + D u + e`` of order n (= ny) to the
    fit rows (records joined, means removed); ``x' = C x`` brings it to the plant file's
    ``C = I`` (``A' = C A C^-1``, ``B' = C B``; D, a feedthrough the sampled plant does not
    have, is dropped) and the means give the offset ``(I - A') y0 - B' u0``. One mode only.
    """
    import pandas as pd  # optional parts: nfoursid (and the pandas it takes) load only here
    from nfoursid.nfoursid import NFourSID
    from nfoursid.utils import Decomposition, Utils

    class _Economic(NFourSID):
        """nfoursid 1.0.2 with the thin SVD of the observability estimate: its full SVD
        makes an N x N matrix (1.2 GB for 12,000 samples) of which it keeps n rows."""

        def _get_observability_matrix_decomposition(self) -> Any:
            uh = Utils.block_hankel_matrix(self.u_array, self.num_block_rows)
            yh = Utils.block_hankel_matrix(self.y_array, self.num_block_rows)
            obs = self.R32 @ np.linalg.pinv(self.R22) @ np.concatenate([uh, yh])
            u, sv, vh = np.linalg.svd(obs, full_matrices=False)
            r = self.x_dim
            return Decomposition(u[:, :r], np.diag(sv[:r]), vh[:r, :])

    if n_modes != 1:
        raise IdentificationError("n4sid: one mode only")
    n = Rf.X.shape[1]
    # the samples in time order: y_k of every row and the last y_{k+1} of each run
    ys, us = [], []
    for rows in _segments(Rf):
        ys.append(np.vstack([Rf.X[rows], Rf.Xn[rows[-1:]]]))
        us.append(np.vstack([Rf.U[rows][:, inputs], Rf.U[rows[-1:]][:, inputs]]))
    Y, U = np.vstack(ys), np.vstack(us)
    y0, u0 = Y.mean(axis=0), U.mean(axis=0)
    ycols = [f"y{i}" for i in range(n)]
    ucols = [f"u{i}" for i in range(inputs.size)]
    df = pd.DataFrame(np.hstack([Y - y0, U - u0]), columns=ycols + ucols)
    i = block_rows or max(n + 1, 4)
    sid = _Economic(df, output_columns=ycols, input_columns=ucols, num_block_rows=i)
    sid.subspace_identification()
    ss, _ = sid.system_identification(rank=n)
    C = np.asarray(ss.c, dtype=float)
    if np.linalg.cond(C) > 1e12:
        raise IdentificationError("n4sid: the identified C is singular")
    Ci = np.linalg.inv(C)
    A = C @ np.asarray(ss.a, dtype=float) @ Ci
    Bf = C @ np.asarray(ss.b, dtype=float)
    B = np.zeros((n, nu))
    B[:, inputs] = Bf
    off = (np.eye(n) - A) @ y0 - Bf @ u0
    return [AffineModel(A, B, off, "affine", int(A.size + Bf.size + n))]


def physical_parameters(adapter: Any, Ms: Sequence[AffineModel], mode_names: Sequence[str],
                        inputs: Sequence[str], outputs: Sequence[str], Ts: float
                        ) -> list[dict[str, Any]]:
    """Inertia, damping (stiffness) and constant torque of every joint the adapter names.

    A joint is a ``sensor_msgs/JointState`` output channel with ``field: velocity`` (and
    optionally ``position``) of one ``joint``; its torque is the input mapped to that joint's
    ``effort``, or an input whose name contains the joint's name, or the only input. The
    joint's rows of the model are read as an isolated joint (couplings to the other channels
    are left out and their size reported).
    """
    if adapter is None:
        return []
    joints: dict[str, dict[str, int]] = {}
    for ch in getattr(adapter, "outputs", ()):
        if getattr(ch, "joint", "") and ch.field in ("position", "velocity") \
                and ch.name in outputs:
            joints.setdefault(ch.joint, {})[ch.field] = list(outputs).index(ch.name)
    out: list[dict[str, Any]] = []
    for joint, f in joints.items():
        if "velocity" not in f:
            continue
        j = next((list(inputs).index(c.name) for c in getattr(adapter, "inputs", ())
                  if getattr(c, "joint", "") == joint and c.field == "effort"
                  and c.name in inputs), None)
        if j is None:
            named = [i for i, nm in enumerate(inputs) if joint in nm]
            j = named[0] if len(named) == 1 else (0 if len(inputs) == 1 else None)
        if j is None:
            out.append({"joint": joint, "note": "no torque input found for this joint"})
            continue
        idx = [f["position"], f["velocity"]] if "position" in f else [f["velocity"]]
        for M, nm in zip(Ms, mode_names):
            rest_A = np.delete(M.A[np.ix_(idx, range(M.A.shape[0]))], idx, axis=1)
            rest_B = np.delete(M.B[idx], j, axis=1)
            if len(idx) == 2:
                p = physical_joint(M.A[np.ix_(idx, idx)], M.B[idx, j], M.offset[idx], Ts)
            else:
                v = idx[0]
                p = physical_velocity(float(M.A[v, v]), float(M.B[v, j]),
                                      float(M.offset[v]), Ts)
            out.append({"joint": joint, "mode": nm, "input": inputs[j],
                        "states": [outputs[i] for i in idx], **p,
                        "coupling_left_out": float(max(np.abs(rest_A).max(initial=0.0),
                                                       np.abs(rest_B).max(initial=0.0))),
                        **({} if p else {"note": "not a stable damped joint (no physical "
                                                 "reading)"})})
    return out
