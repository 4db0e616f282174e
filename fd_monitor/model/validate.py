"""The one validation toolkit of fd_monitor's input files.

Plant files (:mod:`fd_monitor.model.system`), scenarios (:mod:`fd_monitor.model.scenario`),
design files (:mod:`fd_monitor.design._lmi_common` and the designers) and the bag library
(:mod:`fd_monitor.analysis.library`) check their YAML with a :class:`Checker`. Every error is
one line naming the file, the key path and what was expected::

    <file>: <section>.<key>: expected <expectation>, got <what was found>

raised as the file kind's own error class (``SystemFileError``, ``ScenarioError``, ...).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any, NoReturn

import numpy as np

__all__ = ["NAME_RE", "Checker", "Got"]

#: A name of a plant, mode, channel or fault: letters, digits and '_', not starting with a digit.
NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class Got(str):
    """A description of what was found, printed as is (not quoted)."""


class Checker:
    """Validation context of one file (and optionally one section of it).

    Parameters
    ----------
    origin : str
        The file's name, first in every message.
    error : type of Exception
        Raised by :meth:`fail` (the file kind's error class).
    section : str
        Key path prefixed to every key (``"hinf_sc"``); ``""`` for none.
    clip : int or None
        Longest ``repr`` of what was found in a message (longer ones end in ``...``); None:
        no limit.
    max_magnitude : float or None
        Largest magnitude :meth:`number` accepts (None: any finite number).
    type_expected : str
        What :meth:`number` says it expected when the value is not a number at all.
    nonneg_expected : str
        What :meth:`number` says it expected of a negative value where ``nonneg`` is asked.
    """

    def __init__(self, origin: str, error: type[Exception], section: str = "", *,
                 clip: int | None = 60, max_magnitude: float | None = None,
                 type_expected: str = "a finite number",
                 nonneg_expected: str = "a number >= 0") -> None:
        self.origin = origin
        self.error = error
        self.section = section
        self.clip = clip
        self.max_magnitude = max_magnitude
        self.type_expected = type_expected
        self.nonneg_expected = nonneg_expected

    def short(self, v: Any) -> str:
        """``repr(v)`` clipped to :attr:`clip` characters (a :class:`Got` as is)."""
        if isinstance(v, Got):
            return str(v)
        s = repr(v)
        if self.clip is None or len(s) <= self.clip:
            return s
        return s[:self.clip - 3] + "..."

    def fail(self, key: str, expected: str, got: Any = None, *, show: bool = True) -> NoReturn:
        """Raise ``<origin>: <section>.<key>: expected <expected>[, got <got>]``."""
        tail = f", got {self.short(got)}" if show else ""
        if self.section:
            where = f"{self.section}.{key}" if key else self.section
        else:
            where = key
        raise self.error(f"{self.origin}: {where}: expected {expected}{tail}")

    # ---------------------------------------------------------------------------------
    # scalars

    def number(self, key: str, v: Any, *, positive: bool = False, negative: bool = False,
               nonneg: bool = False) -> float:
        """A finite number (optionally > 0, < 0 or >= 0; at most :attr:`max_magnitude`)."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, self.type_expected, v)
        x = float(v)
        if not math.isfinite(x):
            self.fail(key, "a finite number", v)
        if self.max_magnitude is not None and abs(x) > self.max_magnitude:
            self.fail(key, f"a number of magnitude <= {self.max_magnitude:g} (larger ones "
                      f"overflow the simulation and the designs)", v)
        if positive and x <= 0:
            self.fail(key, "a number > 0", v)
        if negative and x >= 0:
            self.fail(key, "a number < 0", v)
        if nonneg and x < 0:
            self.fail(key, self.nonneg_expected, v)
        return x

    def integer(self, key: str, v: Any, minimum: int = 0, expected: str = "") -> int:
        """An integer (not a bool) >= ``minimum``; ``expected`` overrides the message."""
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
            self.fail(key, expected or f"an integer >= {minimum}", v)
        return int(v)

    def boolean(self, key: str, v: Any) -> bool:
        """``true`` or ``false``."""
        if not isinstance(v, bool):
            self.fail(key, "true or false", v)
        return v

    def name(self, key: str, v: Any) -> str:
        """A name of letters, digits and '_' (:data:`NAME_RE`)."""
        if not isinstance(v, str) or not NAME_RE.match(v):
            self.fail(key, "a name of letters, digits and '_'", v)
        return v

    # ---------------------------------------------------------------------------------
    # containers

    def mapping(self, key: str, v: Any, allowed: set[str] | None = None) -> Mapping[str, Any]:
        """A mapping whose keys are in ``allowed`` (when given)."""
        if not isinstance(v, Mapping):
            self.fail(key, "a mapping", v)
        if allowed is not None:
            self.keys(key, v, allowed)
        return v

    def keys(self, key: str, data: Mapping[str, Any], allowed: set[str]) -> None:
        """Refuse the first key of ``data`` not in ``allowed``."""
        for k in data:
            if k not in allowed:
                where = f"{key}.{k}" if key else str(k)
                self.fail(where, f"one of the keys {sorted(allowed)} (unknown key)", show=False)

    def require(self, key: str, data: Mapping[str, Any], names: tuple[str, ...],
                expected: str = "a value (missing key)") -> None:
        """Refuse ``data`` (at ``key``) lacking one of ``names``."""
        for nm in names:
            if nm not in data:
                self.fail(f"{key}.{nm}" if key else nm, expected, show=False)

    def matrix(self, key: str, v: Any, shape: tuple[int | None, int | None]) -> np.ndarray:
        """A matrix given as a list of rows; ``None`` in ``shape`` means any size.

        A matrix of zero rows or columns may be omitted (None, ``[]`` or ``[[]]``).
        """
        rows, cols = shape
        if (rows == 0 or cols == 0) and v in (None, [], [[]]):
            return np.zeros((rows or 0, cols or 0))
        r_txt = rows if rows is not None else "r"
        c_txt = cols if cols is not None else "c"
        if (not isinstance(v, list) or not all(isinstance(r, list) for r in v)
                or (rows is None and not v)):
            self.fail(key, f"a {r_txt}x{c_txt} matrix (a list of rows)", v)
        widths = sorted({len(r) for r in v})
        if ((rows is not None and len(v) != rows) or len(widths) > 1
                or (cols is not None and widths != [cols] and v)):
            self.fail(key, f"a {r_txt}x{c_txt} matrix",
                      Got(f"{len(v)} rows of length {', '.join(map(str, widths))}"))
        out = np.empty((len(v), widths[0] if widths else (cols or 0)))
        for i, r in enumerate(v):
            for j, e in enumerate(r):
                out[i, j] = self.number(f"{key}[{i}][{j}]", e)
        return out

    def vector(self, key: str, v: Any, size: int | None, *, nonneg: bool = False
               ) -> np.ndarray:
        """A list of numbers (of ``size`` entries when given; an empty one may be omitted)."""
        if size == 0 and v in (None, []):
            return np.zeros(0)
        want = f"a list of {size if size is not None else 'some'} numbers"
        if not isinstance(v, list):
            self.fail(key, want, v)
        if size is not None and len(v) != size:
            self.fail(key, want, Got(f"{len(v)} numbers"))
        return np.array([self.number(f"{key}[{i}]", e, nonneg=nonneg)
                         for i, e in enumerate(v)], dtype=float)

    def names(self, key: str, v: Any) -> tuple[str, ...]:
        """A list of unique names (:meth:`name`); None is the empty list."""
        if v is None:
            v = []
        if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
            self.fail(key, "a list of names", v)
        for i, s in enumerate(v):
            self.name(f"{key}[{i}]", s)
        dup = {s for s in v if v.count(s) > 1}
        if dup:
            self.fail(key, "unique names", sorted(dup))
        return tuple(v)
