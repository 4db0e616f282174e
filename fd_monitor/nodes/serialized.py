"""Stamped, labelled Float64MultiArray messages serialized directly (no message object
per sample).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

from rclpy.serialization import serialize_message

from fd_monitor.model.errors import MessageError, WrongLengthError
from fd_monitor.wire.conversions import MAX_STAMP, to_msg

__all__ = ["SerializedArray"]


class SerializedArray:
    """Stamped, labelled Float64MultiArray messages of fixed labels, serialized directly.

    The message of :func:`~fd_monitor.wire.conversions.to_msg` serialized once (CDR, little
    endian); ``data`` is its last field, so a sample's message is that prefix (layout, data
    length) followed by ``[k, *values]`` packed as float64: what a publisher takes as
    serialized bytes, without a message object per sample (the node tests compare every
    published value).

    Parameters
    ----------
    labels : sequence of str
        (m,) channel names.
    batch : bool
        Every message carries the batch mark
        (:data:`~fd_monitor.wire.conversions.BATCH_LABEL`).
    """

    def __init__(self, labels: Sequence[str], batch: bool = False) -> None:
        self.labels = tuple(labels)
        n = len(self.labels) + 1
        cdr = serialize_message(to_msg(self.labels, 0, [0.0] * len(self.labels), batch=batch))
        self.prefix = cdr[:-8 * n]
        self._pack = struct.Struct(f"<{n}d").pack

    def encode(self, stamp: int, values: Any) -> bytes:
        """The serialized message ``[stamp, *values]``; ``values`` (m,) array or list."""
        if not 0 <= stamp < MAX_STAMP:
            raise MessageError(f"stamp {stamp!r} out of range [0, 2**53)")
        vals = values.tolist() if hasattr(values, "tolist") else values
        try:
            return self.prefix + self._pack(stamp, *vals)
        except struct.error:
            raise WrongLengthError(f"{len(self.labels)} labels for {len(vals)} values") from None
