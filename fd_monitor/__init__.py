"""fd_monitor: model-based fault detection for ROS 2 plants and robots.

The public Python API (``doc/reference/api.md``): a plant file, a scenario and a gain file
loaded and checked, a run simulated, a bag read, written and analysed, any gain file's
runtime stepped by hand.

>>> import fd_monitor
>>> plant = fd_monitor.load_system("three_tank")
>>> plant.name, plant.outputs, plant.sample_time
('three_tank', ('h1', 'h2', 'h3'), 0.1)
>>> doc = fd_monitor.analyze_bag("bags/three_tank_bias_h1", "three_tank_thresholds")
>>> doc["detection"], doc["isolated"]
({'sample': 1000, 'time': 100.0}, ['h1'])

Every name is imported on first use (PEP 562 ``__getattr__``), so ``import fd_monitor``
loads none of numpy, yaml or mcap: a command line that imports the package for
``__version__`` stays fast.
"""

from __future__ import annotations

# Not typing.TYPE_CHECKING: importing typing alone would double the package's import time.
TYPE_CHECKING = False

__version__ = "0.1.0"
__all__ = ["__version__", "FdMonitorError", "load_system", "load_scenario", "load_gains",
           "runtime_for", "simulate", "read_bag", "write_bag", "run_bag", "analyze_bag"]

if TYPE_CHECKING:  # the names as mypy and readers see them; imported lazily below
    from typing import Any

    from fd_monitor.analysis.offline import run_bag
    from fd_monitor.commands.analyze import analyze_bag
    from fd_monitor.core.methods import load_gains, runtime_for
    from fd_monitor.core.simulator import simulate
    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.model.scenario import load_scenario
    from fd_monitor.model.system import load_system
    from fd_monitor.wire.bag_reader import read_bag
    from fd_monitor.wire.bag_writer import write_bag


def __getattr__(name: str) -> Any:
    """The public name ``name``, imported on first use (then cached in the module)."""
    # Written out, not a table of strings: test/test_layers.py sees every import here.
    value: Any
    if name == "FdMonitorError":
        from fd_monitor.model.errors import FdMonitorError
        value = FdMonitorError
    elif name == "load_system":
        from fd_monitor.model.system import load_system
        value = load_system
    elif name == "load_scenario":
        from fd_monitor.model.scenario import load_scenario
        value = load_scenario
    elif name == "load_gains":
        from fd_monitor.core.methods import load_gains
        value = load_gains
    elif name == "runtime_for":
        from fd_monitor.core.methods import runtime_for
        value = runtime_for
    elif name == "simulate":
        from fd_monitor.core.simulator import simulate
        value = simulate
    elif name == "read_bag":
        from fd_monitor.wire.bag_reader import read_bag
        value = read_bag
    elif name == "write_bag":
        from fd_monitor.wire.bag_writer import write_bag
        value = write_bag
    elif name == "run_bag":
        from fd_monitor.analysis.offline import run_bag
        value = run_bag
    elif name == "analyze_bag":
        from fd_monitor.commands.analyze import analyze_bag
        value = analyze_bag
    else:
        raise AttributeError(f"module 'fd_monitor' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
