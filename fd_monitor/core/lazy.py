"""Per-sample output objects whose arrays are made when first read.

A single stream computes on Python floats; turning each of its results into a numpy array
cost about 0.45 us per array (eight per sample of the ``thresholds`` chain) and a frozen
dataclass about 1.2 us per object (six per sample), more than the chain's own arithmetic.
A node publishes only the topics someone subscribes to and a benchmark reads nothing, so
the outputs keep the lists they were given and make each array on its first read (then keep
it): what is never read is never converted. The attributes read exactly as before (numpy
arrays of the same dtype: ``np.array`` of the same list), and cannot be assigned.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any, overload

import numpy as np

__all__ = ["Fields", "LazyArray", "Output", "stored_list"]


class LazyArray:
    """A read-only attribute stored in slot ``_<name>``: a list there becomes
    ``np.array(list)`` on the first read (and stays that array); anything else is returned as
    it is (an array of a batch, None)."""

    __slots__ = ("slot",)

    def __init__(self) -> None:
        self.slot = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = "_" + name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> LazyArray: ...

    @overload
    def __get__(self, obj: object, owner: type | None = None) -> Any: ...

    def __get__(self, obj: object | None, owner: type | None = None) -> Any:
        if obj is None:
            return self
        v = getattr(obj, self.slot)
        if type(v) is list:
            v = np.array(v)
            setattr(obj, self.slot, v)
        return v


def stored_list(obj: Any, name: str) -> list[Any] | None:
    """Field ``name`` of an output as a list, without making its array when it has not been
    made (a node reading a few values per sample); None for a None field."""
    v = getattr(obj, "_" + name) if isinstance(getattr(type(obj), name, None), LazyArray) \
        else getattr(obj, name)
    return v if v is None or type(v) is list else np.ravel(v).tolist()


class Fields(Mapping[str, Any]):
    """``payload()`` of an output as a mapping read when asked: ``fields[name]`` is
    ``getattr(obj, name)``, so a node that publishes one topic makes only that topic's
    arrays."""

    __slots__ = ("_names", "_obj")

    def __init__(self, obj: Any, names: tuple[str, ...]) -> None:
        self._obj, self._names = obj, names

    def __getitem__(self, name: str) -> Any:
        if name not in self._names:
            raise KeyError(name)
        return getattr(self._obj, name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


class Output:
    """Base of the per-sample outputs: ``__slots__`` (no instance dict), array fields as
    :class:`LazyArray`, ``FIELDS`` their names in order (for ``repr``)."""

    __slots__ = ()
    FIELDS: tuple[str, ...] = ()

    def __repr__(self) -> str:
        body = ", ".join(f"{n}={getattr(self, n)!r}" for n in self.FIELDS)
        return f"{type(self).__name__}({body})"
