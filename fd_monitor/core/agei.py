"""Autonomous guard events identification, AGEI (Heracleous et al., Sec. 3.3, Fig. 3, eq. 20-22).

Three phases per run:

* **monitoring** (phase 0): for the AGEI-matrix rows whose enabling mode is q^_k, evaluate the
  decision rule lambda (eq. 20) on the filtered measurement ``w_{i,k}`` of the guard's state
  with the band ``Xi^± = (1 ± delta) |H(1) xi|`` (eq. 21). The first row with lambda = 1 starts
  the expecting phase.
* **expecting** (phase 1): the override ``r_bar*`` (eq. 22) of the row is sent to the detector
  (used from k + 1). The event is recognised when an affected residual crosses its *nominal*
  threshold, ``|r_{i,k}| > r_bar_{i,k}``; then the guard is triggered (applied by the observer
  to q^_{k+1}) and the triggering phase starts. If lambda returns 0 (the filtered level left
  the band) without an event, back to monitoring. A row with no affected residual (the two
  modes' models agree past the guard, so no residual can see the event and no false alarm can
  come from it) is executed when ``w_i op H(1) xi`` holds: an extension of Fig. 3 that keeps
  the mode estimate right in that case. If a controlled guard changed q^ while
  expecting, the row with the same condition from the new mode is followed (or monitoring).
* **triggering** (phase 2): ``r_bar*`` is held for K = ``hold_steps`` samples (the filter's
  settling time), then back to monitoring.

With ``enabled=False`` the module is inert (no trigger, no override): the ablation in which the
observer never executes autonomous transitions.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fd_monitor.core.filters import as_floats
from fd_monitor.core.lazy import LazyArray, Output
from fd_monitor.core.thresholds import AgeiRow, DiagnosisGains
from fd_monitor.model.system import System

__all__ = ["Agei", "AgeiOutput", "MONITORING", "EXPECTING", "TRIGGERING"]

MONITORING, EXPECTING, TRIGGERING = 0, 1, 2


def _frozen(a: np.ndarray) -> np.ndarray:
    """A read-only copy (shared by every output that carries it)."""
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a



class AgeiOutput(Output):
    """AGEI decision at sample k (used by observer and detector at k + 1).

    Attributes
    ----------
    k : int
    trigger : int
        Guard index to execute in the observer (q^_{k+1}), or -1 (batch: (N,)).
    override : numpy.ndarray
        (ny,) thresholds for the detector at k + 1; NaN where none (batch: (N, ny)).
    phase : int
        0 monitoring, 1 expecting, 2 triggering (after this sample's decision).
    row : int
        AGEI-matrix row being expected or held, or -1.
    mode_uncertain : bool
        An event that residuals can see is expected or was just executed (phase 1 or 2 on a
        row with affected residuals): q^ may differ from q, so the bias estimator must not
        learn at this sample (batch: (N,)).

    :meth:`payload` names the fields; :mod:`fd_monitor.wire.topics` says which topic
    carries which.
    """

    __slots__ = ("_override", "k", "mode_uncertain", "phase", "row", "trigger")
    #: the keys of :meth:`payload`, in its order
    payload_names = ("trigger", "phase", "row", "mode_uncertain", "override")
    FIELDS = ("k", "trigger", "override", "phase", "row", "mode_uncertain")
    override = LazyArray()

    def __init__(self, k: int, trigger: int | np.ndarray, override: Any,
                 phase: int | np.ndarray, row: int | np.ndarray,
                 mode_uncertain: bool | np.ndarray = False) -> None:
        self.k, self.trigger, self._override = k, trigger, override
        self.phase, self.row, self.mode_uncertain = phase, row, mode_uncertain

    def payload(self) -> dict[str, Any]:
        """Field name -> value: ``trigger``, ``phase``, ``row``, ``mode_uncertain``,
        ``override``."""
        return {"trigger": self.trigger, "phase": self.phase, "row": self.row,
                "mode_uncertain": self.mode_uncertain, "override": self.override}


class Agei:
    """The AGEI module.

    Parameters
    ----------
    system : System
    gains : DiagnosisGains
    batch : int or None
    enabled : bool
        False: never triggers, never overrides (ablation).
    """

    def __init__(self, system: System, gains: DiagnosisGains, *, batch: int | None = None,
                 enabled: bool = True) -> None:
        self.system = system
        self.gains = gains
        self.batch = batch
        self.N = 1 if batch is None else int(batch)
        self.enabled = enabled
        self.rows: tuple[AgeiRow, ...] = gains.agei_rows
        s, ny = len(system.modes), system.ny
        self._star = np.array([r.r_bar_star for r in self.rows]).reshape(len(self.rows), ny)
        self._affected = np.zeros((len(self.rows), ny), dtype=bool)
        for j, r in enumerate(self.rows):
            self._affected[j, list(r.affected)] = True
        self._guard = np.array([r.guard for r in self.rows], dtype=int)
        self._dc = gains.filter.dc_gain
        ops = {"<": 0, "<=": 1, ">": 2, ">=": 3, "==": 4}
        self._op = np.array([ops[r.op] for r in self.rows], dtype=int)
        self._out = np.array([r.output for r in self.rows], dtype=int)
        self._xim = np.array([r.xi_minus for r in self.rows])
        self._xip = np.array([r.xi_plus for r in self.rows])
        self._val = np.array([r.value for r in self.rows])
        self._enab = np.array([r.enabling_mode for r in self.rows], dtype=int)
        # _same[j, m]: the row with row j's condition whose enabling mode is m (or -1)
        self._same = np.full((max(len(self.rows), 1), s), -1, dtype=int)
        for j, r in enumerate(self.rows):
            for j2, r2 in enumerate(self.rows):
                if (r2.state, r2.op, r2.value) == (r.state, r.op, r.value):
                    self._same[j, r2.enabling_mode] = j2
        # single stream: the tables as Python numbers; overrides as shared read-only arrays
        self._rows1 = [(int(self._out[j]), int(self._op[j]), float(self._xim[j]),
                        float(self._xip[j]), self._dc * float(self._val[j]),
                        [i for i in range(ny) if self._affected[j, i]], int(self._guard[j]),
                        int(self._enab[j])) for j in range(len(self.rows))]
        self._same1 = self._same.tolist()
        # per mode, the rows it enables (in row order) with lambda's numbers
        self._enabled1 = [[(j, r[0], r[1], r[2], r[3]) for j, r in enumerate(self._rows1)
                           if r[7] == m] for m in range(s)]
        self._none1 = (_frozen(np.full(ny, np.nan)), [float("nan")] * ny)
        self._star1 = [(_frozen(self._star[j]), self._star[j].tolist())
                       for j in range(len(self.rows))]
        self.reset()

    def reset(self) -> None:
        """Back to monitoring."""
        self.phase = np.zeros(self.N, dtype=int)
        self.row = np.full(self.N, -1, dtype=int)
        self.hold = np.zeros(self.N, dtype=int)
        self._phase1, self._row1, self._hold1 = MONITORING, -1, 0

    def _lam1(self, j: int, w: Sequence[float]) -> bool:
        """lambda (eq. 20) of row j on the filtered measurement w (single stream)."""
        out, op, lo, hi = self._rows1[j][:4]
        aw = abs(w[out])
        if op == 4:
            return lo <= aw <= hi
        return aw >= lo if op >= 2 else aw <= hi

    def step1(self, k: int, mode: int, w: Sequence[float], residual: Sequence[float],
              nominal: Sequence[float]) -> tuple[AgeiOutput, list[float]]:
        """Single stream on Python numbers: the decisions of :meth:`step_batch` for one run.

        Returns the output and its override as a list (for the detector at k + 1).
        """
        trigger = -1
        if not self.enabled or not self.rows:
            return (AgeiOutput(k, trigger, self._none1[0], self._phase1, self._row1, False),
                    self._none1[1])
        phase, row = self._phase1, self._row1
        if phase == TRIGGERING:
            self._hold1 -= 1
            if self._hold1 <= 0:
                phase, row = MONITORING, -1
        if phase == EXPECTING:
            j = self._same1[row][mode]
            if j < 0:
                phase, row = MONITORING, -1
            else:
                row = j
                out, op, _, _, val, aff, guard, _ = self._rows1[j]
                if aff:
                    occurred = any(abs(residual[i]) > nominal[i] for i in aff)
                else:
                    v = w[out]
                    occurred = (v < val if op == 0 else v <= val if op == 1 else
                                v > val if op == 2 else v >= val if op == 3 else v == val)
                if occurred:
                    trigger, phase = guard, TRIGGERING
                    self._hold1 = self.gains.hold_steps if aff else 0
                elif not self._lam1(j, w):
                    phase, row = MONITORING, -1
        if phase == MONITORING:
            for jj, out, op, lo, hi in self._enabled1[mode]:   # lambda (eq. 20), as _lam1
                aw = abs(w[out])
                if (lo <= aw <= hi) if op == 4 else (aw >= lo if op >= 2 else aw <= hi):
                    phase, row = EXPECTING, jj
                    break
        self._phase1, self._row1 = phase, row
        ov = self._none1 if row < 0 else self._star1[row]
        return (AgeiOutput(k, trigger, ov[0], phase, row, row >= 0 and bool(self._rows1[row][5])),
                ov[1])

    def _lam_rows(self, rows: np.ndarray, w: np.ndarray) -> np.ndarray:
        """lambda (eq. 20) of row ``rows[i]`` on run i's filtered measurement: (M,) bool."""
        aw = np.abs(w[np.arange(rows.size), self._out[rows]])
        op = self._op[rows]
        lo, hi = self._xim[rows], self._xip[rows]
        return np.where(op == 4, (aw >= lo) & (aw <= hi), np.where(op >= 2, aw >= lo, aw <= hi))

    def _holds_rows(self, rows: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``w_i op H(1) xi`` of row ``rows[i]`` (no-affected rows): (M,) bool."""
        v = w[np.arange(rows.size), self._out[rows]]
        val = self._dc * self._val[rows]
        op = self._op[rows]
        return np.select([op == 0, op == 1, op == 2, op == 3], [v < val, v <= val, v > val,
                                                                v >= val], v == val)

    def step_batch(self, k: int, mode: np.ndarray, w: np.ndarray, residual: np.ndarray,
                   nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batched step: (N,), (N, ny) x3 -> (trigger (N,), override (N, ny))."""
        N, ny = self.N, self.system.ny
        trigger = np.full(N, -1, dtype=int)
        override = np.full((N, ny), np.nan)
        if not self.enabled or not self.rows:
            return trigger, override
        phase, row = self.phase, self.row
        # triggering phase: count down the hold
        hold = phase == TRIGGERING
        if hold.any():
            self.hold[hold] -= 1
            done = hold & (self.hold <= 0)
            phase[done] = MONITORING
            row[done] = -1
        # expecting: follow a controlled mode change, then test recognition / lambda
        exp = np.nonzero(phase == EXPECTING)[0]
        if exp.size:
            j = self._same[row[exp], mode[exp]]
            lost = j < 0
            phase[exp[lost]] = MONITORING
            row[exp[lost]] = -1
            exp, j = exp[~lost], j[~lost]
            row[exp] = j
            aff = self._affected[j]
            over = (np.abs(residual[exp]) > nominal[exp]) & aff
            occurred = np.where(aff.any(axis=1), over.any(axis=1),
                                self._holds_rows(j, w[exp]))
            occ = exp[occurred]
            trigger[occ] = self._guard[j[occurred]]
            phase[occ] = TRIGGERING
            self.hold[occ] = np.where(aff[occurred].any(axis=1), self.gains.hold_steps, 0)
            rest = ~occurred
            left = rest.copy()
            left[rest] = ~self._lam_rows(j[rest], w[exp[rest]])
            phase[exp[left]] = MONITORING
            row[exp[left]] = -1
        # monitoring: enter expecting on the first row with lambda = 1
        for jj in range(len(self.rows)):
            sel = np.nonzero((phase == MONITORING) & (mode == self._enab[jj]))[0]
            if sel.size:
                hit = sel[self._lam_rows(np.full(sel.size, jj), w[sel])]
                phase[hit] = EXPECTING
                row[hit] = jj
        active = row >= 0
        if active.any():
            override[active] = self._star[row[active]]
        return trigger, override

    def step(self, k: int, mode: int | np.ndarray, w: np.ndarray, residual: np.ndarray,
             nominal: np.ndarray) -> AgeiOutput:
        """Process sample k.

        Parameters
        ----------
        k : int
        mode : int
            q^_k (observer).
        w : numpy.ndarray
            (ny,) w_k = H[y~]_k (detector).
        residual : numpy.ndarray
            (ny,) r_k (detector).
        nominal : numpy.ndarray
            (ny,) nominal threshold r_bar at k (detector).

        Returns
        -------
        AgeiOutput
        """
        if self.batch is None:
            return self.step1(k, int(mode), as_floats(w), as_floats(residual),
                              as_floats(nominal))[0]
        t, o = self.step_batch(k, np.asarray(mode, int), w, residual, nominal)
        return AgeiOutput(k, t, o, self.phase.copy(), self.row.copy(), self.mode_uncertain())

    def mode_uncertain(self) -> np.ndarray:
        """(N,) bool: phase expecting/triggering on a row with affected residuals."""
        if self.batch is None:
            r = self._row1
            return np.array([r >= 0 and bool(self._rows1[r][5])])
        if not self.rows:
            return np.zeros(self.N, dtype=bool)
        has = np.asarray(self._affected.any(axis=1), dtype=bool)
        return np.asarray((self.row >= 0) & has[np.maximum(self.row, 0)])
