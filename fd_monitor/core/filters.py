"""Residual filters H(z) of the sensor-bias diagnosis chain (Heracleous et al., eq. 8-9).

A filter is a proper, asymptotically stable transfer function

    H(z) = (d_0 + d_1 z^-1 + ... + d_m z^-m) / (1 + c_1 z^-1 + ... + c_m z^-m)    (eq. 8)

stored as numerator ``b = [d_0 .. d_m]`` and denominator ``a = [1, c_1 .. c_m]`` (FIR: ``a =
[1]``). ``H_p(z) = z^-1 H(z)`` has impulse response ``h_p(t) = h(t - 1)``.

:class:`FilterBank` runs one filter on many channels and many runs at once, one sample per
call, in direct form I. Its arithmetic is elementwise with a fixed summation order (taps summed
in index order along the first axis), so one run gives the same bits whether it is filtered alone
or inside a batch: the in-process :class:`~fd_monitor.core.monitor.Monitor`, the batch runner and
the ROS nodes all agree exactly.

Initial condition: the filter starts in the steady state of its first input (as if that value
had been applied forever), so ``H[c] = H(1) c`` from the first sample on and the AGEI decision
rule (eq. 20) has no warm-up transient. The residual ``r = H[y~] - H[x^]`` starts at zero because
the observer starts at ``x^_0 = y~_0``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["FilterSpec", "FilterBank", "FloatFilter", "as_floats", "linear_map", "moving_average",
           "first_order", "impulse_response", "settling_length"]


@dataclass(frozen=True)
class FilterSpec:
    """A SISO discrete filter ``H(z) = B(z^-1) / A(z^-1)`` (eq. 8), applied to every channel.

    Attributes
    ----------
    b : numpy.ndarray
        (m_b + 1,) numerator coefficients d_0 .. d_m.
    a : numpy.ndarray
        (m_a + 1,) denominator coefficients, ``a[0] == 1``; ``[1.0]`` for an FIR filter.
    kind : str
        ``"fir"`` or ``"iir"`` (informative).
    """

    b: np.ndarray
    a: np.ndarray
    kind: str = "fir"

    def __post_init__(self) -> None:
        b = np.asarray(self.b, dtype=float).ravel()
        a = np.asarray(self.a, dtype=float).ravel()
        if b.size == 0 or a.size == 0 or not np.all(np.isfinite(b)) or \
                not np.all(np.isfinite(a)):
            raise ValueError("filter: b and a must be non-empty finite vectors")
        if a[0] != 1.0:
            raise ValueError(f"filter: a[0] must be 1 (normalised denominator), got {a[0]}")
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "a", a)

    @property
    def is_fir(self) -> bool:
        """True when the denominator is 1."""
        return self.a.size == 1

    def poles(self) -> np.ndarray:
        """Poles of H(z) (roots of ``z^m + c_1 z^(m-1) + ... + c_m``); empty for FIR."""
        if self.is_fir:
            return np.zeros(0)
        return np.roots(self.a)

    def spectral_radius(self) -> float:
        """Largest pole modulus (0 for FIR): the filter is asymptotically stable iff < 1."""
        p = self.poles()
        return float(np.max(np.abs(p))) if p.size else 0.0

    @property
    def dc_gain(self) -> float:
        """H(1)."""
        return float(self.b.sum() / self.a.sum())


def moving_average(length: int) -> FilterSpec:
    """FIR moving average of ``length`` samples, ``H(1) = 1``."""
    if length < 1:
        raise ValueError(f"moving average: length must be >= 1, got {length}")
    return FilterSpec(np.full(length, 1.0 / length), np.array([1.0]), "fir")


def first_order(pole: float) -> FilterSpec:
    """IIR low-pass ``(1 - p) / (1 - p z^-1)``, ``0 <= p < 1``, ``H(1) = 1``."""
    if not 0.0 <= pole < 1.0:
        raise ValueError(f"first-order filter: pole must be in [0, 1), got {pole}")
    return FilterSpec(np.array([1.0 - pole]), np.array([1.0, -pole]), "iir")


def impulse_response(spec: FilterSpec, length: int) -> np.ndarray:
    """First ``length`` samples h(0), h(1), ... of the impulse response of ``spec``.

    Returns
    -------
    numpy.ndarray
        (length,) dimensionless.
    """
    h = np.zeros(length)
    b, a = spec.b, spec.a
    for t in range(length):
        acc = b[t] if t < b.size else 0.0
        for j in range(1, min(a.size, t + 1)):
            acc -= a[j] * h[t - j]
        h[t] = acc
    return h


def settling_length(spec: FilterSpec, tol: float = 1e-9, max_length: int = 100000) -> int:
    """Number of samples K after which ``sum_{t >= K} |h(t)| <= tol`` (FIR: its length).

    For an IIR filter the tail is bounded from the spectral radius rho:
    ``|h(t)| <= c rho^t`` is checked numerically on twice the returned horizon.
    """
    if spec.is_fir:
        return int(spec.b.size)
    rho = spec.spectral_radius()
    if rho >= 1.0:
        raise ValueError("filter is not asymptotically stable")
    n = 64
    while n <= max_length:
        h = impulse_response(spec, 2 * n)
        tail = np.cumsum(np.abs(h)[::-1])[::-1]  # tail[t] = sum_{s >= t} |h(s)|
        # geometric bound of what lies beyond the computed horizon
        extra = np.abs(h[-1]) * rho / (1.0 - rho) if rho > 0 else 0.0
        idx = np.nonzero(tail + extra <= tol)[0]
        if idx.size:
            return int(max(idx[0], 1))
        n *= 2
    raise ValueError(f"filter does not settle to {tol} within {max_length} samples")


class FilterBank:
    """One filter H(z) applied to an (N, c) array of channels, one sample per :meth:`step`.

    Parameters
    ----------
    spec : FilterSpec
    shape : tuple of int
        (N, c): runs x channels.

    Notes
    -----
    Direct form I: ``out_k = sum_j b_j in_{k-j} - sum_{j>=1} a_j out_{k-j}``. Histories are kept
    in arrays shifted by one slot per sample (tiny: (m + 1, N, c)). Sums run in tap order along
    axis 0, so results do not depend on N.
    """

    def __init__(self, spec: FilterSpec, shape: tuple[int, int]) -> None:
        self.spec = spec
        self.shape = shape
        self._b = spec.b[:, None, None]
        self._a = spec.a[1:, None, None]
        self._xin = np.zeros((spec.b.size, *shape))
        self._yout = np.zeros((max(spec.a.size - 1, 0), *shape))
        self.started = False

    def reset(self) -> None:
        """Forget the history: the next input initialises the steady state again."""
        self._xin[...] = 0.0
        self._yout[...] = 0.0
        self.started = False

    def step(self, x: np.ndarray) -> np.ndarray:
        """Filter one sample.

        Parameters
        ----------
        x : numpy.ndarray
            (N, c) input at sample k.

        Returns
        -------
        numpy.ndarray
            (N, c) output at sample k.
        """
        if not self.started:
            # steady state of the constant input x: in = x, out = H(1) x
            self._xin[...] = x
            if self._yout.shape[0]:
                self._yout[...] = self.spec.dc_gain * x
            self.started = True
        else:
            self._xin[1:] = self._xin[:-1]
            self._xin[0] = x
        out = (self._b * self._xin).sum(axis=0)
        if self._yout.shape[0]:
            out = out - (self._a * self._yout).sum(axis=0)
            self._yout[1:] = self._yout[:-1]
            self._yout[0] = out
        return out


def linear_map(rows: Sequence[Sequence[tuple[float, int]]]) -> Callable[[Sequence[float]],
                                                                         list[float]]:
    """``f(h) = [sum_j c_ij h[idx_ij] for each row i]``, each sum left to right.

    Left to right is the order numpy adds the taps of :meth:`FilterBank.step`'s
    ``sum(axis=0)`` (it reduces a non-contiguous leading axis one slice at a time) and the
    terms of a contiguous row of up to 7 (``bias_estimator.matvec``), so the single stream
    on Python floats gets the batch path's bits. Built once as one expression with the
    coefficients as constants (their ``repr`` round-trips exactly): a Python loop over the
    terms costs several times more per sample.

    Parameters
    ----------
    rows : sequence of sequence of (float, int)
        Per output, its (coefficient, index into h) terms in summation order (non-empty).
    """
    exprs = [" + ".join(f"({float(c)!r}) * h[{int(i)}]" for c, i in row) for row in rows]
    return eval(f"lambda h: [{', '.join(exprs)}]")


class FloatFilter:
    """One filter H(z) on ``channels`` channels of one stream, on Python floats.

    The single-stream form of :class:`FilterBank` (same initial condition, same direct form
    I, same summation order: the same bits as a batch of one), without numpy calls. The
    histories are rings of slots (one value per channel each); :func:`linear_map` gives one
    function per ring position, so a sample costs one slot write and one call.

    Parameters
    ----------
    spec : FilterSpec
    channels : int
    """

    def __init__(self, spec: FilterSpec, channels: int) -> None:
        self.spec = spec
        c = self.channels = int(channels)
        nb, na = self._nb, self._na = spec.b.size, spec.a.size - 1
        # position p holds in_k; tap j reads slot (p - j) mod nb (out: (p - j + 1) mod na)
        self._fb = [linear_map([[(spec.b[j], ((p - j) % nb) * c + ch) for j in range(nb)]
                                for ch in range(c)]) for p in range(nb)]
        self._fa = [linear_map([[(spec.a[j], ((p - j + 1) % na) * c + ch)
                                 for j in range(1, na + 1)] for ch in range(c)])
                    for p in range(na)]
        self._dc = spec.dc_gain
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next input initialises the steady state again."""
        self._x: list[float] = []
        self._y: list[float] = []
        self._px = self._py = 0
        self.started = False

    def step(self, x: Sequence[float]) -> list[float]:
        """Filter one sample: (channels,) floats in -> (channels,) floats out."""
        c = self.channels
        if not self.started:
            # steady state of the constant input x: in = x, out = H(1) x
            self._x = list(x) * self._nb
            self._y = [self._dc * v for v in x] * self._na
            self._px = self._py = 0
            self.started = True
        else:
            p = self._px = (self._px + 1) % self._nb
            self._x[p * c:(p + 1) * c] = x
        out = self._fb[self._px](self._x)
        if self._na:
            out = [o - v for o, v in zip(out, self._fa[self._py](self._y))]
            p = self._py = (self._py + 1) % self._na
            self._y[p * c:(p + 1) * c] = out
        return out


def as_floats(v: Sequence[float] | np.ndarray) -> list[float]:
    """A vector as a list of Python floats (the single-stream paths' inputs)."""
    return np.ravel(v).tolist() if isinstance(v, np.ndarray) else [float(a) for a in v]
