"""Flow control of the sources that run flat out: acknowledgement pacing and Fast DDS
profiles.

Acknowledgements travel on Fast DDS heartbeats, whose default period (3 s) would make each
wait last about a second; :func:`use_dds_profile` points Fast DDS at
``config/fastdds_pacing.xml`` (2 ms heartbeats) in such a source and at ``config/fastdds.xml``
(20 ms) in the other nodes, unless the user chose a profile file.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from rclpy.duration import Duration

from fd_monitor.model.paths import config_dirs

__all__ = ["AckPacer", "PROFILES", "use_dds_profile", "wait_for_subscribers"]


class AckPacer:
    """Block every ``window`` publications until every matched reader acknowledged.

    Parameters
    ----------
    publishers : sequence of rclpy.publisher.Publisher
    window : int
        Publications between waits; must be below the publishers' history depth so no
        unacknowledged sample can be overwritten.
    timeout : float
        s to wait for acknowledgements before giving up (a reader that vanished).
    """

    def __init__(self, publishers: Sequence[Any], window: int, timeout: float = 10.0) -> None:
        self.publishers = list(publishers)
        self.window = max(1, int(window))
        self.timeout = Duration(seconds=float(timeout))
        self._count = 0

    def published(self) -> bool:
        """Count one publication round; wait at the end of a window. False on timeout."""
        self._count += 1
        if self._count % self.window:
            return True
        return self.flush()

    def flush(self) -> bool:
        """Wait until every publisher's samples are acknowledged. False on timeout."""
        return all(p.wait_for_all_acked(self.timeout) for p in self.publishers)


def wait_for_subscribers(publishers: Sequence[tuple[Any, int]]) -> bool:
    """True when every ``(publisher, n)`` has at least ``n`` matched subscriptions."""
    return all(p.get_subscription_count() >= n for p, n in publishers)


# -- DDS profile -----------------------------------------------------------------------------

_PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


#: fd_monitor's Fast DDS profiles: nodes, and sources that pace by acknowledgements.
PROFILES = {False: "fastdds.xml", True: "fastdds_pacing.xml"}


def use_dds_profile(pacing: bool = False) -> str | None:
    """Point Fast DDS at one of fd_monitor's profiles before rclpy starts.

    ``pacing`` (``plant_sim``, ``replay``: sources that wait for acknowledgements):
    ``config/fastdds_pacing.xml``, 2 ms heartbeats, so each wait lasts milliseconds. Else
    ``config/fastdds.xml``, 20 ms heartbeats: a lost sample is still repaired within tens of
    milliseconds, and a node's writers do not pay 500 heartbeats a second each (the
    four-process chain spent 0.7 ms of CPU per sample on them: README, "Measured").

    Does nothing when the user set a profile file already (one not of fd_monitor), or when
    the XML is not found. Child processes inherit it (and choose again). Returns the profile
    in force, if any.
    """
    dirs = list(config_dirs())
    ours = {str(d / name) for d in dirs for name in PROFILES.values()}
    for var in _PROFILE_VARS:
        if os.environ.get(var) and os.environ[var] not in ours:
            return os.environ[var]
    for d in dirs:
        xml = d / PROFILES[pacing]
        if xml.is_file():
            for var in _PROFILE_VARS:
                os.environ[var] = str(xml)
            return str(xml)
    return None
