"""Test configuration: isolate DDS and ROS logs for the whole run.

Every test run gets its own ROS_DOMAIN_ID and localhost-only discovery, so tests never see
(or disturb) another ROS graph on the machine; ROS logs go to a temporary folder.
"""

from __future__ import annotations

import os
import random
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

# Set before any rclpy import (the RMW reads them at init).
# Asks for UDP only (Fast DDS's shared-memory transport can hang at start on segments a killed
# process left in /dev/shm, and tests kill processes on purpose). Measured (h-dds, issue 25):
# under ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, set below, rmw_fastrtps builds its own
# transports (shared memory + UDP) and ignores this; it takes effect for a wider range only.
os.environ.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
try:
    import importlib.util

    _ROS = importlib.util.find_spec("rclpy") is not None
except (ImportError, ValueError):
    _ROS = False
if _ROS:
    # localhost discovery and a domain nobody else on this (shared) machine is using
    from fd_monitor.nodes.domain import isolate_env

    # pytest-xdist workers (``-n 2``) each take a domain from their own residue class, so two
    # workers starting together never probe, find free and take the same id
    _worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    _count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    _ids = None
    if _worker.startswith("gw") and _count > 1:
        _ids = [d for d in range(1, 101) if d % _count == int(_worker[2:]) % _count]
        # the controller's own ROS_DOMAIN_ID (it ran this file first) reaches every worker
        # in its environment: kept, all workers would share one domain and hear each other
        os.environ.pop("ROS_DOMAIN_ID", None)
    isolate_env(os.environ, keep_domain=True, candidates=_ids)
elif "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="fd_monitor_roslog_"))
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.pop("FD_MONITOR_CONFIG", None)
if _ROS:
    # The domain stays visibly taken between tests, for the probe of another run
    from fd_monitor.nodes.domain import hold_domain

    _ANCHOR = hold_domain()


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture(scope="session")
def python() -> str:
    """The interpreter running the tests (the project's .venv under scripts/test.sh)."""
    return sys.executable


@pytest.fixture(scope="session")
def shipped_design():
    """``get(plant, method)``: the designer's output for the plant's own design file, computed
    once per session (designs are deterministic; test_hminus_fk, test_hinf_53_65 and
    test_shipped_thresholds check the same ones). Each call returns a deep copy."""
    import copy

    cache: dict[tuple[str, str], dict] = {}

    def get(name: str, method: str) -> dict:
        if (name, method) not in cache:
            from fd_monitor.design import hinf_sc, hminus_switched
            from fd_monitor.design._lmi_common import load_design_section
            from fd_monitor.model.system import load_system

            s = load_system(name)
            sec, origin, sha = load_design_section(s, method)
            designer = {"hinf_sc": hinf_sc, "hminus_switched": hminus_switched}[method]
            cache[(name, method)] = designer.design(s, sec, origin, sha)
        return copy.deepcopy(cache[(name, method)])

    return get


@pytest.fixture(scope="session")
def scenario_run():
    """``get(scenario)``: ``simulate(load_scenario(scenario))`` (its own seed and duration),
    once per session (simulations are deterministic; the thesis overlap runs are checked by
    test_hinf_53_65 and test_shipped_thresholds). Each call returns a deep copy."""
    import copy

    cache: dict[str, object] = {}

    def get(name: str):
        if name not in cache:
            from fd_monitor.core.simulator import simulate
            from fd_monitor.model.scenario import load_scenario

            cache[name] = simulate(load_scenario(name))
        return copy.deepcopy(cache[name])

    return get


# The files that take longest (15-60 s each on this project's 2-core machine), longest
# first. Run first, so that with pytest-xdist (``--dist loadfile`` hands out files in this
# order) no long file starts last on one worker while the other sits idle: the suite's wall
# time is then close to half its CPU time. Unlisted files keep their collection order.
HEAVY = ("test_nodes_burst", "test_demo", "test_regression_live", "test_regenerate",
         "test_shipped_thresholds", "test_workspace", "test_robot_example",
         "test_timebase", "test_robot_commands", "test_monitor_single_stream",
         "test_identify_three_tank", "test_pipeline", "test_live_recovery", "test_lint",
         "test_envelope", "test_evaluate", "test_robot_live", "test_runtime",
         "test_diagnosis_core", "test_hinf_affine", "test_timebase_live", "test_fleet")


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config,
                                  items: list[pytest.Item]) -> None:
    """Order the collected tests: the files of :data:`HEAVY` first, in its order (stable, so
    tests keep their order within a file)."""
    rank = {name: i for i, name in enumerate(HEAVY)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(HEAVY)))
