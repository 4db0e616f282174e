"""The tests' assertion on a regenerated bag: :func:`fd_monitor.wire.bag_compare.bag_differences`
(record by record, values within :data:`~fd_monitor.wire.bag_compare.SIM_RTOL` of each topic's
scale: another machine's rounding, not a change). Bit-for-bit stays where one process makes
both sides (two writers fed the same arrays in one run)."""

from __future__ import annotations

from pathlib import Path

from fd_monitor.wire.bag_compare import SIM_RTOL, bag_differences

__all__ = ["SIM_RTOL", "assert_bags_close"]


def assert_bags_close(got: str | Path, want: str | Path, rtol: float = SIM_RTOL) -> None:
    """Assert that bag ``got`` holds the records of ``want`` within ``rtol``."""
    diffs = bag_differences(got, want, rtol)
    assert not diffs, "; ".join(diffs[:5])
