"""One fused fd_monitor per robot namespace.

    ros2 launch fd_monitor monitor.launch.py robots:=robot1,robot2
    ros2 launch fd_monitor monitor.launch.py robots:=robot1 params_file:=my_monitor.yaml

Each robot ``R`` gets the node ``/R/monitor``: it reads ``/R/plant/u`` and ``/R/plant/y`` and
publishes ``/R/fd/*`` (relative names), its statuses on ``/diagnostics`` with hardware_id
``R/<plant>``. Parameters: ``config/launch/monitor.yaml`` (keys ``/**/monitor``).
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

#: config/launch/ beside launch/ (the source tree and share/fd_monitor/ alike)
PARAMS = Path(__file__).resolve().parent.parent / "config" / "launch" / "monitor.yaml"


def monitors(context):
    """One monitor node per name in ``robots``."""
    robots = [r.strip() for r in LaunchConfiguration("robots").perform(context).split(",")]
    params = LaunchConfiguration("params_file").perform(context)
    return [Node(package="fd_monitor", executable="monitor", name="monitor", namespace=r,
                 parameters=[params], output="screen") for r in robots if r]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("robots", default_value="robot1",
                              description="robot namespaces, comma-separated"),
        DeclareLaunchArgument("params_file", default_value=str(PARAMS),
                              description="ROS 2 parameter file of the monitors"),
        OpaqueFunction(function=monitors),
    ])
