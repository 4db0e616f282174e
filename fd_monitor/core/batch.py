"""Result of a batch replay of a detection method over a simulated :class:`Trajectory`.

Every detection method offers a batch runner with the signature::

    run_batch(system, gains, traj: Trajectory, **options) -> BatchResult

reached through the runtime registry (:meth:`fd_monitor.core.runtime.Runtime.run_batch` of
``fd_monitor.core.methods.RUNTIMES[method]``).
The evaluation (false-alarm rate, detection rate and delay) reads only :attr:`BatchResult.alarm`
and :attr:`BatchResult.channels`; the optional arrays are for plots and extra metrics.

This module is neutral (numpy only) so that every method's runner can import it. Its fields are
stable: new fields are added only with a default.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["BatchResult"]


@dataclass(frozen=True)
class BatchResult:
    """Per-sample outputs of a detection method over a batch of N runs of K samples.

    Attributes
    ----------
    alarm : numpy.ndarray
        (N, K, n_channels) bool: alarm flag of each channel at each sample, as the method would
        publish it as the alarm at that sample (no latching).
    channels : tuple of str
        (n_channels,) names of the alarm channels, in the order of ``alarm``'s last axis.
    residual : numpy.ndarray or None
        (N, K, n_channels) the signal each channel compares with its threshold (units of the
        channel), or None.
    threshold : numpy.ndarray or None
        (K, n_channels) or (N, K, n_channels) the threshold in force, or None.
    x_hat : numpy.ndarray or None
        (N, K, n) state estimate (state units), or None.
    mode_hat : numpy.ndarray or None
        (N, K) int estimated mode, or None.
    extra : mapping
        Method-specific named arrays or scalars (free-form, for reports).
    """

    alarm: np.ndarray
    channels: tuple[str, ...]
    residual: np.ndarray | None = None
    threshold: np.ndarray | None = None
    x_hat: np.ndarray | None = None
    mode_hat: np.ndarray | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.alarm.ndim != 3:
            raise ValueError(f"BatchResult.alarm: expected an (N, K, n_channels) array, got "
                             f"shape {self.alarm.shape}")
        if self.alarm.shape[2] != len(self.channels):
            raise ValueError(f"BatchResult.channels: expected {self.alarm.shape[2]} names "
                             f"(alarm's last axis), got {len(self.channels)}")

    @property
    def any_alarm(self) -> np.ndarray:
        """(N, K) bool: some channel alarms at that sample."""
        return np.asarray(self.alarm.any(axis=2))
