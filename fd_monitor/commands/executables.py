"""The executables of fd_monitor: name -> module with ``main()``.

One table feeds the console scripts and the ``lib/fd_monitor/`` launchers (``setup.py`` reads
this file without importing the package), and ``python -m fd_monitor run <node>``.
"""

__all__ = ["EXECUTABLES", "NODES"]

EXECUTABLES: dict[str, str] = {
    "fd_monitor": "fd_monitor.commands.cli",
    "plant_sim": "fd_monitor.nodes.plant_sim",
    "observer": "fd_monitor.nodes.observer",
    "detector": "fd_monitor.nodes.detector",
    "agei": "fd_monitor.nodes.agei",
    "bias_estimator": "fd_monitor.nodes.bias_estimator",
    "monitor": "fd_monitor.nodes.monitor",
    "replay": "fd_monitor.commands.replay",
    "record": "fd_monitor.commands.record",
    "design": "fd_monitor.commands.design",
    "report": "fd_monitor.commands.report",
}

#: The ROS 2 nodes among them (``python -m fd_monitor run <node>``).
NODES: dict[str, str] = {n: m for n, m in EXECUTABLES.items()
                         if m.startswith("fd_monitor.nodes.")}
