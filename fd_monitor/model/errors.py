"""Errors raised by fd_monitor.

Every error carries a one-line message that names *where* the problem is (a file and a
key path, a topic, a sample) and *what* was expected. The command line prints
``fd_monitor: error: <message>`` and exits with status 2; nodes log the message and report it
on ``/diagnostics`` without stopping.
"""

from __future__ import annotations

__all__ = [
    "FdMonitorError",
    "SystemFileError",
    "ScenarioError",
    "GainFileError",
    "DesignError",
    "BagError",
    "MessageError",
    "FdMonitorWarning",
    "ImplausibleError",
    "NonFiniteError",
    "WrongLengthError",
]


#: Every character str.splitlines() breaks on -> its escaped form.
_LINE_BREAKS = {ord(c): c.encode("unicode_escape").decode() for c in
                "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"}


class FdMonitorError(Exception):
    """Base class of every error fd_monitor raises on purpose."""

    def __str__(self) -> str:
        # One line whatever a file put into a key or value the message quotes.
        return super().__str__().translate(_LINE_BREAKS)


class SystemFileError(FdMonitorError, ValueError):
    """A plant description is missing, unreadable or invalid."""


class ScenarioError(FdMonitorError, ValueError):
    """A scenario file (inputs, faults, duration) is invalid."""


class GainFileError(FdMonitorError, ValueError):
    """A gain file is invalid, for another plant, or its certificate does not hold."""


class DesignError(FdMonitorError, RuntimeError):
    """A designer could not produce a gain file (infeasible LMI, solver failure, ...)."""


class BagError(FdMonitorError, OSError):
    """A bag is missing, unreadable, or lacks a topic that is needed."""


class MessageError(FdMonitorError, ValueError):
    """A message is malformed (wrong length, NaN/Inf, missing stamp)."""


class FdMonitorWarning(UserWarning):
    """Something the user should know that did not stop the work (a damaged bag's chunk
    skipped, ...); the command line prints ``fd_monitor: warning: <message>``."""


class ImplausibleError(MessageError):
    """A finite sample outside the plant's physical range or far from its prediction."""


class NonFiniteError(MessageError):
    """A message holds NaN or Inf where finite numbers are expected."""


class WrongLengthError(MessageError):
    """A message holds another number of values than its layout, labels or plant say."""
