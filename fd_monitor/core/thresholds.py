"""Gains of the sensor-bias diagnosis chain (method ``thresholds``) and their certificate.

The designer (:mod:`fd_monitor.design.thresholds`) writes, and this module reads and re-checks,
everything the runtime core needs (Heracleous et al., eq. 8-26):

``results`` of a ``thresholds`` gain file
    filter            {kind, b, a}: H(z) of eq. 8
    impulse           {h, h_p, h_p_bar}: (K_h,) impulse responses; h_p_bar >= |h_p|
    hold_steps        K: samples for h to settle (AGEI triggering phase, eq. 22)
    noise_bound       (ny,) v_bar, output units
    v_F_bar           (ny,) eq. 9: ||h||_1 v_bar (for reference; not used by the threshold)
    linear_part       (s, n, n) A_q: the linear(ised) noise propagation of mode q
    noise_l1          (s, ny) combined l1 bound of the linear map v -> r per mode (see below)
    eta_bar           (s, ny) modelling-uncertainty bound per mode (the plant file's)
    remainder_bar     (s, ny) per-sample bound of the nonlinear remainder (Monte Carlo + margin)
    r_bar             (s, ny) steady nominal threshold (eq. 19 with the combined bound)
    r_bar_separate    (s, ny) eq. 19 with v_F_bar and Delta-f_bar bounded separately (reference)
    agei              {delta, rows: [...]}: the AGEI matrix with r_bar_star per row (eq. 20-22)
    estimator         {Lambda, Gamma, M_sigma, isolation_threshold, isolation_delay}
    mode_names, output_names

Threshold used at run time (mode sequence q^_k estimated by the observer)::

    R_{i,k} = max_q noise_l1[q, i] + sum_{m >= 1} h_p_bar(m) (eta_bar + remainder_bar)[q^_{k-m}, i]

i.e. the constant noise term plus ``H_p_bar[eta_bar(q^) + remainder_bar(q^)]`` filtered on line
(the paper's ``H_p_bar(z)[eta_bar_i(q^_k)]``). ``r_bar`` is its value after K samples in one mode.

:func:`check_certificate` recomputes from ``results`` and the plant: the filter is stable and
its stored impulse responses match, the majorant dominates |h_p|, the combined noise bound and
r_bar follow from the stored parts, r_bar_star >= r_bar, the AGEI rows match the plant's
autonomous guards, Lambda is Schur, Gamma symmetric positive definite, M_sigma > 0, and the
linearised estimator error dynamics are Schur in every mode.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from fd_monitor.core.envelope import CertifiedRegion
from fd_monitor.core.filters import FilterSpec, impulse_response
from fd_monitor.model.errors import GainFileError
from fd_monitor.model.system import System

__all__ = ["AgeiRow", "DiagnosisGains", "check_certificate", "noise_l1_bound",
           "estimator_error_matrix", "DEFAULT_DELTA"]

#: AGEI decision-rule band (eq. 21), fraction of |H(1) xi|.
DEFAULT_DELTA = 0.05


@dataclass(frozen=True)
class AgeiRow:
    """One row of the AGEI matrix: an autonomous guard event g_aj (Sec. 3.3).

    Attributes
    ----------
    guard : int
        Index of the guard in ``system.guards``.
    name : str
    enabling_mode, target_mode : int
        Mode indices (q_Ij and q*_Ij).
    state : int
        Index of the state x_i of the enabling condition ``x_i op xi``.
    op : str
    value : float
        xi_aj, state units.
    output : int
        Output measuring that state (y = x + v): the filtered measurement w_i it is tested on.
    affected : tuple of int
        Outputs whose residuals the event affects.
    xi_minus, xi_plus : float
        Xi^-_aj, Xi^+_aj of eq. 21, state units.
    r_bar_star : numpy.ndarray
        (ny,) expecting-phase thresholds (eq. 22); equal to the nominal one off ``affected``.
    mismatch_bar : numpy.ndarray
        (ny,) per-sample bound of the mode-mismatch term |f(q*, x) - f(q^, x)| in the guard band.
    """

    guard: int
    name: str
    enabling_mode: int
    target_mode: int
    state: int
    op: str
    value: float
    output: int
    affected: tuple[int, ...]
    xi_minus: float
    xi_plus: float
    r_bar_star: np.ndarray
    mismatch_bar: np.ndarray


@dataclass(frozen=True)
class DiagnosisGains:
    """Everything the runtime core reads from a ``thresholds`` gain file.

    Attributes
    ----------
    filter : FilterSpec
        H(z), eq. 8.
    h, h_p, h_p_bar : numpy.ndarray
        (K_h,) impulse responses of H, H_p = z^-1 H and the majorant H_p_bar.
    hold_steps : int
        K (AGEI triggering phase).
    noise_bound : numpy.ndarray
        (ny,) v_bar.
    noise_l1 : numpy.ndarray
        (s, ny) combined noise-to-residual l1 bound per mode.
    eta_bar, remainder_bar : numpy.ndarray
        (s, ny) per-sample bounds (modelling uncertainty; nonlinear remainder).
    r_bar : numpy.ndarray
        (s, ny) steady nominal thresholds.
    delta : float
        AGEI band (eq. 21).
    agei_rows : tuple of AgeiRow
    Lambda, Gamma : numpy.ndarray
        (n, n) estimator gains (eq. 23, 25).
    M_sigma : float
        Radius of the projection ball Theta_sigma (eq. 26), output units.
    isolation_threshold : numpy.ndarray
        (ny,) |sigma^_i| above which sensor i is isolated as faulty, output units.
    isolation_delay : int
        Samples after the detection before isolation flags are raised.
    estimator_init : str
        ``presmoother`` (fault-free state estimate at K_d) or ``measurement`` (eq. 23:
        ``x^s_{K_d} = y_{K_d}``).
    presmoother_gain : float
        alpha in (0, 1) of the delayed pre-detection observer.
    presmoother_delay : int
        D, samples (> the filter memory).
    region : CertifiedRegion or None
        Where the bounds hold (``results.envelope``); None for files without it.
    """

    filter: FilterSpec
    h: np.ndarray
    h_p: np.ndarray
    h_p_bar: np.ndarray
    hold_steps: int
    noise_bound: np.ndarray
    noise_l1: np.ndarray
    eta_bar: np.ndarray
    remainder_bar: np.ndarray
    r_bar: np.ndarray
    delta: float
    agei_rows: tuple[AgeiRow, ...]
    Lambda: np.ndarray
    Gamma: np.ndarray
    M_sigma: float
    isolation_threshold: np.ndarray
    isolation_delay: int
    estimator_init: str = "presmoother"
    presmoother_gain: float = 0.02
    presmoother_delay: int = 1
    region: CertifiedRegion | None = None
    #: The gain-file method these gains belong to (the runtime registry's key).
    method: ClassVar[str] = "thresholds"

    @property
    def noise_term(self) -> np.ndarray:
        """(ny,) mode-independent noise part of the threshold: ``max_q noise_l1[q]``."""
        return np.asarray(self.noise_l1.max(axis=0))

    @property
    def per_sample_bound(self) -> np.ndarray:
        """(s, ny) ``eta_bar + remainder_bar``: what H_p_bar filters on line."""
        return np.asarray(self.eta_bar + self.remainder_bar)

    @classmethod
    def from_results(cls, system: System, results: Mapping[str, Any]) -> DiagnosisGains:
        """Build from a gain file's ``results`` mapping (arrays already numpy).

        Raises
        ------
        GainFileError
            When a key is missing or a shape is wrong (message names the key).
        """
        ny, n, s = system.ny, system.n, len(system.modes)
        spec = _filter_spec(results)   # in this order: the first missing key is reported
        h, h_p, h_p_bar = _impulse(results)
        delta, rows = _agei_rows(system, results)
        est = _section(results, "estimator", "a mapping")
        where = "results.estimator"
        return cls(
            filter=spec, h=h, h_p=h_p, h_p_bar=h_p_bar,
            hold_steps=int(results.get("hold_steps", 0)),
            noise_bound=_array(results, "noise_bound", (ny,)),
            noise_l1=_array(results, "noise_l1", (s, ny)),
            eta_bar=_array(results, "eta_bar", (s, ny)),
            remainder_bar=_array(results, "remainder_bar", (s, ny)),
            r_bar=_array(results, "r_bar", (s, ny)),
            delta=delta,
            agei_rows=rows,
            Lambda=_array(est, "Lambda", (n, n), where),
            Gamma=_array(est, "Gamma", (n, n), where),
            M_sigma=float(_array(est, "M_sigma", (), where)),
            isolation_threshold=_array(est, "isolation_threshold", (ny,), where),
            isolation_delay=int(est.get("isolation_delay", 0)),
            estimator_init=str(est.get("init", "measurement")),
            presmoother_gain=float(est.get("presmoother_gain", 0.02)),
            presmoother_delay=int(est.get("presmoother_delay", 1)),
            region=CertifiedRegion.from_results(system, results),
        )


def _array(src: Mapping[str, Any], key: str, shape: tuple[int, ...] | None,
           where: str = "results") -> np.ndarray:
    """``src[key]`` as a finite float array of ``shape`` (any when None); ``GainFileError``
    naming ``where.key`` otherwise."""
    if key not in src:
        raise GainFileError(f"{where}.{key}: missing")
    a = np.asarray(src[key], dtype=float)
    if shape is not None and a.shape != shape:
        raise GainFileError(f"{where}.{key}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise GainFileError(f"{where}.{key}: expected finite numbers")
    return a


def _section(results: Mapping[str, Any], key: str, expected: str) -> Mapping[str, Any]:
    """``results[key]`` when it is a mapping; ``GainFileError`` naming it otherwise."""
    sec = results.get(key)
    if not isinstance(sec, Mapping):
        raise GainFileError(f"results.{key}: expected {expected}")
    return sec


def _filter_spec(results: Mapping[str, Any]) -> FilterSpec:
    """H(z) of ``results.filter`` (eq. 8)."""
    flt = _section(results, "filter", "a mapping {kind, b, a}")
    try:
        return FilterSpec(np.atleast_1d(_array(flt, "b", None, "results.filter")),
                          np.atleast_1d(_array(flt, "a", None, "results.filter")),
                          str(flt.get("kind", "fir")))
    except ValueError as exc:
        raise GainFileError(f"results.filter: {exc}") from None


def _impulse(results: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(h, h_p, h_p_bar), each (K_h,), of ``results.impulse``."""
    imp = _section(results, "impulse", "a mapping {h, h_p, h_p_bar}")
    h = np.atleast_1d(_array(imp, "h", None, "results.impulse"))
    K_h = h.size
    return (h, np.atleast_1d(_array(imp, "h_p", (K_h,), "results.impulse")),
            np.atleast_1d(_array(imp, "h_p_bar", (K_h,), "results.impulse")))


def _agei_rows(system: System, results: Mapping[str, Any]
               ) -> tuple[float, tuple[AgeiRow, ...]]:
    """(delta, rows) of ``results.agei``, names resolved against the plant."""
    ag = results.get("agei")
    if not isinstance(ag, Mapping) or "rows" not in ag:
        raise GainFileError("results.agei: expected a mapping {delta, rows}")
    ny, names = system.ny, system.outputs
    rows = []
    for j, r in enumerate(ag["rows"] or []):
        where = f"results.agei.rows[{j}]"
        try:
            rows.append(AgeiRow(
                guard=int(r["guard"]), name=str(r["name"]),
                enabling_mode=system.mode_index(str(r["enabling_mode"])),
                target_mode=system.mode_index(str(r["target_mode"])),
                state=system.states.index(str(r["state"])), op=str(r["op"]),
                value=float(r["value"]), output=names.index(str(r["output"])),
                affected=tuple(names.index(str(a)) for a in r["affected"]),
                xi_minus=float(r["xi_minus"]), xi_plus=float(r["xi_plus"]),
                r_bar_star=_array(r, "r_bar_star", (ny,), where),
                mismatch_bar=_array(r, "mismatch_bar", (ny,), where)))
        except (KeyError, ValueError, TypeError) as exc:
            raise GainFileError(f"{where}: {type(exc).__name__}: {exc}") from None
    return float(ag.get("delta", DEFAULT_DELTA)), tuple(rows)


def as_gains(system: System, gains: Any) -> DiagnosisGains:
    """Accept a :class:`DiagnosisGains`, a loaded ``GainFile`` or a ``results`` mapping."""
    if isinstance(gains, DiagnosisGains):
        return gains
    results = getattr(gains, "results", gains)
    method = getattr(gains, "method", "thresholds")
    if method != "thresholds":
        raise GainFileError(f"gain file method {method!r}: the diagnosis chain needs a "
                            f"'thresholds' gain file (python -m fd_monitor design thresholds "
                            f"{system.name})")
    if not isinstance(results, Mapping):
        raise GainFileError("expected a thresholds gain file or its results mapping")
    return DiagnosisGains.from_results(system, results)


def noise_l1_bound(h: np.ndarray, A: np.ndarray, v_bar: np.ndarray) -> np.ndarray:
    """Exact l1 bound of the linear map from the noise sequence v to the residual r.

    With ``x^_{k+1} = f(q, y~_k, u_k)`` and ``f(q, x + v) - f(q, x) = A v + remainder``, the
    prediction error is ``e_k = v_k - A v_{k-1} + ...`` and ``r = H[e]``, so
    ``r_{i,k} = sum_m sum_l (delta_il h(m) - A_il h(m - 1)) v_{l,k-m}`` and

        sup |r_i| = sum_l v_bar_l sum_m |delta_il h(m) - A_il h(m - 1)|.

    Parameters
    ----------
    h : numpy.ndarray
        (K_h,) impulse response of H (the tail beyond K_h must be negligible).
    A : numpy.ndarray
        (n, n) linear part (n = ny, full-state measurement).
    v_bar : numpy.ndarray
        (ny,) noise bounds.

    Returns
    -------
    numpy.ndarray
        (ny,) bound, output units.
    """
    hh = np.concatenate([h, [0.0]])
    hp = np.concatenate([[0.0], h])  # h(m - 1)
    n = A.shape[0]
    out = np.zeros(n)
    for i in range(n):
        for l in range(n):
            coef = (hh if i == l else 0.0 * hh) - A[i, l] * hp
            out[i] += v_bar[l] * float(np.abs(coef).sum())
    return out


def estimator_error_matrix(J: np.ndarray, Lambda: np.ndarray, Gamma: np.ndarray) -> np.ndarray:
    """Linearised error dynamics of the bias estimator (eq. 23-25) around a Jacobian J.

    With ``x~ = x^s - x`` and ``sigma~ = sigma^ - sigma``: ``eps = -x~ - sigma~ + v`` and

        [x~; sigma~]_{k+1} = [[J - Lambda, -Lambda], [-Gamma, I - Gamma]] [x~; sigma~] + ...

    Returns
    -------
    numpy.ndarray
        (2n, 2n)
    """
    n = J.shape[0]
    top = np.hstack([J - Lambda, -Lambda])
    bot = np.hstack([-Gamma, np.eye(n) - Gamma])
    return np.vstack([top, bot])


def check_certificate(system: System, gains: Any) -> None:
    """Re-verify a ``thresholds`` gain file against ``system`` (numpy only).

    Parameters
    ----------
    system : System
    gains : GainFile
        As loaded by :func:`fd_monitor.core.methods.load_gains`.

    Raises
    ------
    GainFileError
        Naming the first check that fails.
    """
    g = as_gains(system, gains)
    cert = getattr(gains, "certificate", {}) or {}
    if system.ny != system.n or not all(np.allclose(m.C, np.eye(system.n)) for m in
                                        system.modes):
        raise GainFileError("the diagnosis chain needs full-state measurements y = x + v (C = I)")
    _check_filter(g)
    _check_bounds(system, g, cert)
    _check_agei(system, g)
    _check_estimator(system, g, cert)


#: Absolute tolerance of the stored bounds against the recomputed ones.
_TOL = 1e-9


def _check_filter(g: DiagnosisGains) -> None:
    """The filter is stable, its stored impulse responses match, the majorant dominates
    |h_p|, they are not truncated and hold_steps covers the filter's memory."""
    rho = g.filter.spectral_radius()
    if not rho < 1.0:
        raise GainFileError(f"filter H(z) is not asymptotically stable (spectral radius {rho})")
    K_h = g.h.size
    h = impulse_response(g.filter, K_h)
    if not np.allclose(h, g.h, rtol=0, atol=1e-12):
        raise GainFileError("impulse.h does not match the filter coefficients")
    if not np.allclose(g.h_p[1:], h[:-1], rtol=0, atol=1e-12) or g.h_p[0] != 0.0:
        raise GainFileError("impulse.h_p is not z^-1 h")
    if np.any(g.h_p_bar < np.abs(g.h_p) - _TOL):
        raise GainFileError("impulse.h_p_bar does not dominate |h_p|")
    if not g.filter.is_fir:
        tail = abs(float(impulse_response(g.filter, K_h + 1)[-1]))
        if tail > 1e-6:
            raise GainFileError("impulse responses are truncated before the filter settles")
    if g.hold_steps < (g.filter.b.size if g.filter.is_fir else 1):
        raise GainFileError(f"hold_steps {g.hold_steps} shorter than the filter's memory")


def _check_bounds(system: System, g: DiagnosisGains, cert: Mapping[str, Any]) -> None:
    """The noise and uncertainty bounds are the plant's, noise_l1 dominates the l1 bound
    recomputed from the certificate's linear parts, and r_bar is derived from its parts."""
    if not np.allclose(g.noise_bound, system.measurement_noise, rtol=1e-12, atol=0):
        raise GainFileError("noise_bound differs from the plant's measurement_noise")
    unc = np.array([m.uncertainty for m in system.modes])
    if np.any(g.eta_bar < unc - _TOL):
        raise GainFileError("eta_bar is below the plant's modelling-uncertainty bounds")
    if "linear_part" not in cert:
        raise GainFileError("certificate.linear_part: missing")
    lin = np.asarray(cert["linear_part"], dtype=float)
    if lin.shape != (len(system.modes), system.n, system.n):
        raise GainFileError("certificate.linear_part: wrong shape")
    for q in range(len(system.modes)):
        nl1 = noise_l1_bound(g.h, lin[q], g.noise_bound)
        if np.any(g.noise_l1[q] < nl1 * (1 - 1e-9) - 1e-15):
            raise GainFileError(f"noise_l1[{system.modes[q].name}] is below the recomputed "
                                f"l1 bound {nl1.tolist()}")
        rb = g.noise_term + float(g.h_p_bar.sum()) * g.per_sample_bound[q]
        # r_bar is derived (the runtime applies the schedule built from its parts): an
        # edited r_bar would change nothing, so it is refused rather than ignored.
        if np.any(np.abs(g.r_bar[q] - rb) > 1e-9 * np.abs(rb)):
            raise GainFileError(f"r_bar[{system.modes[q].name}] differs from noise_l1 + "
                                f"||h_p_bar||_1 (eta_bar + remainder_bar) = {rb.tolist()}: "
                                f"r_bar is derived; change noise_l1, eta_bar or remainder_bar "
                                f"(or redesign) to change the thresholds")


def _check_agei(system: System, g: DiagnosisGains) -> None:
    """One AGEI row per autonomous guard, each matching its guard, r_bar_star >= r_bar."""
    for j, row in enumerate(g.agei_rows):
        if not 0 <= row.guard < len(system.guards):
            raise GainFileError(f"agei.rows[{j}]: no guard {row.guard}")
        gd = system.guards[row.guard]
        if gd.kind != "autonomous" or gd.source != row.enabling_mode or \
                gd.target != row.target_mode or len(gd.conditions) != 1:
            raise GainFileError(f"agei.rows[{j}] does not match guard {gd.name!r}")
        c = gd.conditions[0]
        if c.index != row.state or c.op != row.op or c.value != row.value:
            raise GainFileError(f"agei.rows[{j}]: condition differs from guard {gd.name!r}")
        if np.any(row.r_bar_star < g.r_bar[row.enabling_mode] * (1 - 1e-9)):
            raise GainFileError(f"agei.rows[{j}]: r_bar_star below the nominal r_bar")
    auto = [i for i, gd in enumerate(system.guards) if gd.kind == "autonomous"]
    if sorted(r.guard for r in g.agei_rows) != auto:
        raise GainFileError("the AGEI matrix must have one row per autonomous guard")


def _check_estimator(system: System, g: DiagnosisGains, cert: Mapping[str, Any]) -> None:
    """Lambda Schur, Gamma SPD, a valid initialisation, M_sigma > 0 and the linearised error
    dynamics Schur at every mode's Jacobian of the certificate."""
    lam_rho = float(np.max(np.abs(np.linalg.eigvals(g.Lambda))))
    if not lam_rho < 1.0:
        raise GainFileError(f"Lambda is not Schur stable (spectral radius {lam_rho:.6g})")
    if not np.allclose(g.Gamma, g.Gamma.T, rtol=0, atol=1e-12):
        raise GainFileError("Gamma is not symmetric")
    if not float(np.min(np.linalg.eigvalsh(g.Gamma))) > 0.0:
        raise GainFileError("Gamma is not positive definite")
    if g.estimator_init not in ("presmoother", "measurement"):
        raise GainFileError(f"estimator.init: expected presmoother or measurement, got "
                            f"{g.estimator_init!r}")
    if g.estimator_init == "presmoother":
        if not 0.0 < g.presmoother_gain < 1.0:
            raise GainFileError("estimator.presmoother_gain must be in (0, 1)")
        if g.presmoother_delay <= g.hold_steps:
            raise GainFileError("estimator.presmoother_delay must exceed hold_steps (the "
                                "filter memory)")
    if not g.M_sigma > 0.0:
        raise GainFileError("M_sigma must be > 0")
    jac = cert.get("jacobians")
    if jac is not None:
        for q, J in enumerate(np.asarray(jac, dtype=float)):
            E = estimator_error_matrix(J, g.Lambda, g.Gamma)
            sr = float(np.max(np.abs(np.linalg.eigvals(E))))
            if not sr < 1.0:
                raise GainFileError(f"estimator error dynamics not Schur in mode "
                                    f"{system.modes[q].name} (spectral radius {sr:.9g})")
