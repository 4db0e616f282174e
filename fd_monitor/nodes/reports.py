"""The per-sample reports of the diagnosis nodes: small objects built from what they need.

Each report owns one or more ``/diagnostics`` channels of a node and the log lines that go
with them; the node that runs the component holds it (composition) and calls it once per
sample:

- :class:`EstimateReport`: the ``estimate`` status of a node running an observer (observer,
  monitor): the mode, WARN outside the gain file's certified region;
- :class:`ResidualReport`: one ``residual <channel>`` status per channel and the alarm
  episode log lines of a detecting node (detector, monitor);
- :class:`BiasReport`: the bias estimator's status (``estimate`` on bias_estimator,
  ``bias estimate`` on monitor) and its detection and isolation log lines.

The fault verdict's report (:class:`~fd_monitor.nodes.fault.FaultReport`) also publishes
``fd/fault``: it has its own module.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fd_monitor.core.envelope import describe_excess
from fd_monitor.model.system import System
from fd_monitor.nodes.diagnostics import ERROR, OK, WARN, Diagnostics

__all__ = ["BiasReport", "EstimateReport", "ResidualReport", "mode_name"]

#: Gain-file id and certificate status for a status's values (the node's ``gain_values``:
#: the gain file can be swapped at runtime).
GainValues = Callable[[], dict[str, str]]


def mode_name(system: System, mode: int) -> str:
    """The plant's name of mode index ``mode`` (the index itself when it has none: a
    switching signal outside the design)."""
    modes = system.mode_names
    return modes[mode] if 0 <= mode < len(modes) else str(mode)


class EstimateReport:
    """The ``estimate`` status: q^ and x^, WARN outside the certified region (one log line
    when it leaves it).

    Parameters
    ----------
    diag : Diagnostics
        Has the ``estimate`` channel.
    logger : rclpy logger
    system : System
        Mode names; state and input names of the region's entries.
    gain_values : callable
        () -> gain-file id and certificate status.
    """

    def __init__(self, diag: Diagnostics, logger: Any, system: System,
                 gain_values: GainValues) -> None:
        self.diag, self.logger, self.system = diag, logger, system
        self.gain_values = gain_values
        self.was_outside = False

    def report(self, k: int, mode: int, x_hat: Any, out: Any,
               names: Sequence[str] | None = None) -> None:
        """Report q^_k, x^_k and the excess ``out`` over the certified region (None: no
        region; ``names``: of its entries, default the states then the inputs)."""
        name = mode_name(self.system, mode)
        values = {"sample": k, "mode": name, "x_hat": x_hat, **self.gain_values()}
        if out is not None and np.any(out != 0.0):
            # alarms still count; the thresholds are just not guaranteed out there
            detail = describe_excess(names if names is not None
                                     else (*self.system.states, *self.system.inputs), out)
            if not self.was_outside:
                self.logger.warning(f"sample {k}: outside certified region: {detail}")
            self.was_outside = True
            self.diag.update("estimate", WARN, f"outside certified region: {detail}",
                             {**values, "outside_certified_region": detail})
        else:
            self.was_outside = False
            self.diag.update("estimate", OK, f"mode {name}", values)


class ResidualReport:
    """Per-channel ``residual <name>`` statuses and the alarm log lines of a detecting node.

    Parameters
    ----------
    diag : Diagnostics
        Has one channel per entry of ``channels``.
    logger : rclpy logger
    system : System
        Mode names.
    channels : sequence of str
        The status names (``residual <channel>``), in the order of the signals.
    warn_share : callable
        () -> the ``warn_share`` parameter (settable at runtime).
    gain_values : callable
        () -> gain-file id and certificate status.
    """

    def __init__(self, diag: Diagnostics, logger: Any, system: System, channels: Sequence[str],
                 warn_share: Callable[[], float], gain_values: GainValues) -> None:
        self.diag, self.logger, self.system = diag, logger, system
        self.channels = list(channels)
        self.warn_share, self.gain_values = warn_share, gain_values
        #: channels in alarm at the last sample, and the alarm episodes so far
        self.alarmed: set[str] = set()
        self.episode = 0

    def report(self, k: int, mode: int, signal: Any, threshold: Any, alarm: Any,
               sigma_hat: Any = None, note: str = "") -> None:
        """Sample k's statuses: ERROR on alarm, WARN above ``warn_share`` x threshold, else
        OK; ``sigma_hat``: the latest bias estimate per channel (thresholds), or None;
        ``note``: appended to an alarm's message (the detector while agei is absent)."""
        share = self.warn_share()
        self.log_alarms(k, signal, threshold, alarm, note)
        for i, ch in enumerate(self.channels):
            r, R = float(signal[i]), float(threshold[i])
            if alarm[i]:
                level, msg = ERROR, f"alarm: |residual| > threshold{note}"
            elif abs(r) > share * R:
                level, msg = WARN, f"|residual| > {share:g} x threshold"
            else:
                level, msg = OK, "ok"
            values = {"sample": k, "residual": r, "threshold": R, "margin": R - abs(r),
                      "mode": mode_name(self.system, mode), **self.gain_values()}
            if sigma_hat is not None:
                values["sigma_hat"] = float(sigma_hat[i])
            self.diag.update(ch, level, msg, values)

    def log_alarms(self, k: int, signal: Any, threshold: Any, alarm: Any,
                   note: str = "") -> None:
        """One line when a channel's alarm starts (``note`` appended), one when every alarm
        is over."""
        now = {ch for i, ch in enumerate(self.channels) if alarm[i]}
        log = self.logger
        if now and not self.alarmed:
            self.episode += 1
        for i, ch in enumerate(self.channels):
            if ch in now and ch not in self.alarmed:
                log.warning(f"alarm episode {self.episode}: {ch} at sample {k}: "
                            f"|r| = {abs(float(signal[i])):.4g} > R = "
                            f"{float(threshold[i]):.4g}{note}")
        if self.alarmed and not now:
            log.info(f"alarm episode {self.episode} over at sample {k}: every residual "
                     f"within its threshold")
        self.alarmed = now


class BiasReport:
    """The bias estimator's status and log lines (detection, isolation).

    Parameters
    ----------
    diag : Diagnostics
        Has the channel ``channel``.
    logger : rclpy logger
    outputs : sequence of str
        The plant's output names (the estimate's entries).
    gain_values : callable
        () -> gain-file id and certificate status.
    channel : str
        The status name (``estimate`` on bias_estimator, ``bias estimate`` on monitor).
    """

    def __init__(self, diag: Diagnostics, logger: Any, outputs: Sequence[str],
                 gain_values: GainValues, channel: str = "estimate") -> None:
        self.diag, self.logger, self.outputs = diag, logger, tuple(outputs)
        self.gain_values, self.channel = gain_values, channel
        self.reset()

    def reset(self) -> None:
        """Nothing detected nor isolated (a new run)."""
        self.last_active = False
        self.last_isolated: list[str] = []

    def report(self, k: int, out: Any) -> None:
        """Report the estimator's output at k (a BiasOutput)."""
        isolated = [o for o, f in zip(self.outputs, out.isolated) if f]
        log = self.logger
        if out.active and not self.last_active:
            log.info(f"fault detected at sample {int(out.k_detect)}: estimating the sensor "
                     f"bias")
        if isolated != self.last_isolated:
            est = ", ".join(f"{o} = {float(v):.4g}" for o, v in zip(self.outputs, out.sigma_hat))
            log.info(f"sample {k}: isolated {', '.join(isolated) or 'nothing'} "
                     f"(sigma_hat {est})")
        self.last_active, self.last_isolated = bool(out.active), isolated
        if out.active:
            level, msg = WARN, (f"bias on {', '.join(isolated)}" if isolated
                                else "estimating (fault detected)")
        else:
            level, msg = OK, "no fault detected"
        self.diag.update(self.channel, level, msg, {
            "sample": k, "active": bool(out.active), "k_detect": int(out.k_detect),
            "sigma_hat": out.sigma_hat, "isolated": ",".join(isolated) or "none",
            **self.gain_values()})
