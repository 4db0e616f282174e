"""fd_monitor: model-based fault detection for ROS 2 plants and robots."""

__version__ = "0.1.0"
__all__ = ["__version__"]
