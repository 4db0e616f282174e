"""Inputs and outputs over the sample index: the one "u, y over k" type of fd_monitor.

A bag read through the input contract (:func:`fd_monitor.analysis.offline.read_streams`), a
robot's bag through an adapter (:class:`fd_monitor.wire.adapters.AdaptedStreams`) and the
records ``identify`` fits (:class:`fd_monitor.analysis.identify.Dataset`) are all a
:class:`Series`; each adds only what is its own (the adapter's time base, identify's mode
channel and provenance).

>>> import numpy as np
>>> s = Series("run1", ("q",), ("h1", "h2"), np.arange(3), np.zeros((3, 1)), np.ones((3, 2)))
>>> len(s), s.y.shape
(3, (3, 2))
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Series"]


@dataclass(frozen=True)
class Series:
    """Inputs u and outputs y over the sample index k.

    Attributes
    ----------
    name : str
        Where they came from (a bag path), for messages.
    inputs, outputs : tuple of str
        Channel names, (nu,) and (ny,).
    k : numpy.ndarray
        (K,) int sample indices, in the order the samples were taken (a new run starts again
        lower; a gap is a hole).
    u : numpy.ndarray
        (K, nu) inputs.
    y : numpy.ndarray
        (K, ny) measurements.
    sample_time : float or None
        s; None when the source does not say.
    side : dict
        Side signals, name -> (K, ...) (``rho``, ``mode``), when read (keyword only).
    """

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    k: np.ndarray
    u: np.ndarray
    y: np.ndarray
    sample_time: float | None = None
    #: keyword-only, so a subclass's own fields follow ``sample_time`` positionally
    side: dict[str, np.ndarray] = field(default_factory=dict, kw_only=True)

    def __len__(self) -> int:
        return int(np.asarray(self.k).size)
