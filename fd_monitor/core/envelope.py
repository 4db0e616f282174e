"""The certified region of a gain file, checked on every sample.

A ``thresholds`` design bounds the nonlinear remainder and the mode mismatch (Heracleous et
al., Assumption 4: rho_bar, mu_bar) over a region of states and inputs: the plant file's
declared operating envelope (``source: declared``) or the bounding box of the simulated design
scenarios (``source: scenarios``). The gain file stores that region per mode
(``results.envelope``); outside it the thresholds are still applied but no longer guaranteed.
:class:`CertifiedRegion` says, per sample, which variable is outside and by how much.

``results.envelope`` of a gain file::

    source       declared | scenarios
    state_lo     (s, n) per-mode state ranges, state units
    state_hi     (s, n)
    input_lo     (s, nu) per-mode input ranges, input units
    input_hi     (s, nu)
    input_source declared | scenarios (``source: scenarios`` only: where the input ranges come
                 from, the plant's declared envelope or the design runs)
    remainder    {method: interval | exact | sampled, ...}: how rho_bar was obtained
    mismatch     {method: sampled, samples, margin}: how mu_bar (AGEI) was obtained
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fd_monitor.model.errors import GainFileError
from fd_monitor.model.system import System

__all__ = ["CertifiedRegion", "describe_excess"]


@dataclass(frozen=True)
class CertifiedRegion:
    """Per-mode boxes of states and inputs where a gain file's bounds hold.

    Attributes
    ----------
    source : str
        ``declared`` (the plant file's envelope) or ``scenarios`` (simulated design runs).
    state_lo, state_hi : numpy.ndarray
        (s, n) state units.
    input_lo, input_hi : numpy.ndarray
        (s, nu) input units.
    names : tuple of str
        State names then input names (the order of :meth:`excess`).
    """

    source: str
    state_lo: np.ndarray
    state_hi: np.ndarray
    input_lo: np.ndarray
    input_hi: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def from_results(cls, system: System, results: Mapping[str, Any]) -> CertifiedRegion | None:
        """The region of a gain file's ``results`` (None for files written before it existed).

        Raises
        ------
        GainFileError
            Malformed ``results.envelope`` (the message names the key).
        """
        env = results.get("envelope")
        if env is None:
            return None
        if not isinstance(env, Mapping):
            raise GainFileError("results.envelope: expected a mapping")
        s, n, nu = len(system.modes), system.n, system.nu
        arrs = []
        for key, shape in (("state_lo", (s, n)), ("state_hi", (s, n)), ("input_lo", (s, nu)),
                           ("input_hi", (s, nu))):
            if key not in env:
                raise GainFileError(f"results.envelope.{key}: missing")
            a = np.asarray(env[key], dtype=float).reshape(-1)
            if a.size != s * (shape[1]):
                raise GainFileError(f"results.envelope.{key}: expected shape {shape}")
            a = a.reshape(shape)
            if not np.all(np.isfinite(a)):
                raise GainFileError(f"results.envelope.{key}: expected finite numbers")
            arrs.append(a)
        if np.any(arrs[0] > arrs[1]) or np.any(arrs[2] > arrs[3]):
            raise GainFileError("results.envelope: expected lo <= hi")
        return cls(str(env.get("source", "declared")), arrs[0], arrs[1], arrs[2], arrs[3],
                   (*system.states, *system.inputs))

    def excess(self, q: int | np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Signed distance outside the box of mode q: 0 inside, > 0 above, < 0 below.

        Parameters
        ----------
        q : int or numpy.ndarray
            Mode (batch: (N,) int).
        x : numpy.ndarray
            (n,) estimated state (batch: (N, n)).
        u : numpy.ndarray
            (nu,) inputs (batch: (N, nu)).

        Returns
        -------
        numpy.ndarray
            (n + nu,) (batch: (N, n + nu)), states then inputs, their units.
        """
        xs = np.concatenate([np.asarray(x, float), np.asarray(u, float)], axis=-1)
        lo = np.concatenate([self.state_lo[q], self.input_lo[q]], axis=-1)
        hi = np.concatenate([self.state_hi[q], self.input_hi[q]], axis=-1)
        return np.asarray(xs - np.clip(xs, lo, hi))


def describe_excess(names: Sequence[str], excess: np.ndarray) -> str:
    """``"h1 above by 0.031, q2 below by 1e-05"`` for the nonzero entries of :meth:`excess`."""
    parts = [f"{n} {'above' if e > 0 else 'below'} by {abs(float(e)):.3g}"
             for n, e in zip(names, np.ravel(excess)) if e != 0.0]
    return ", ".join(parts)
