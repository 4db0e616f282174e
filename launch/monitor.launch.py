"""One fused fd_monitor per robot namespace.

    ros2 launch fd_monitor monitor.launch.py robots:=robot1,robot2
    ros2 launch fd_monitor monitor.launch.py robots:=robot1 params_file:=my_monitor.yaml
    ros2 launch fd_monitor monitor.launch.py robots:=r0,r1,r2,r3 processes:=2

Each robot ``R`` gets the node ``/R/monitor``: it reads ``/R/plant/u`` and ``/R/plant/y`` and
publishes ``/R/fd/*`` (relative names), its statuses on ``/diagnostics`` with hardware_id
``R/<plant>``. Parameters: ``config/launch/monitor.yaml`` (keys ``/**/monitor``, or
``/R/monitor`` for one robot). ``processes`` (default 0: one process per robot): the robots
spread in order over that many ``monitor`` processes, each hosting its share on one executor
and one DDS participant (``-p robots:=[...]``): a process per robot costs ~65 MB and a
participant each; one Python process uses at most one core, so take about one process per
core for a large fleet (30 robots on 2 cores: ``processes:=2``).
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

#: config/launch/ beside launch/ (the source tree and share/fd_monitor/ alike)
PARAMS = Path(__file__).resolve().parent.parent / "config" / "launch" / "monitor.yaml"


def monitors(context):
    """One monitor node per name in ``robots``: a process each, or spread over
    ``processes`` processes."""
    robots = [r.strip() for r in LaunchConfiguration("robots").perform(context).split(",")]
    robots = [r for r in robots if r]
    params = LaunchConfiguration("params_file").perform(context)
    k = min(int(LaunchConfiguration("processes").perform(context) or 0), len(robots))
    if k <= 0:
        return [Node(package="fd_monitor", executable="monitor", name="monitor", namespace=r,
                     parameters=[params], output="screen") for r in robots]
    # contiguous shares whose sizes differ by at most one; no name remap (every process's
    # nodes are "monitor", in their robots' namespaces). The share as one comma-separated
    # string: launch_ros writes a list as a !!python/tuple, which rcl reads but a parameter
    # file check refuses.
    n = len(robots)
    return [Node(package="fd_monitor", executable="monitor",
                 parameters=[params, {"robots": ",".join(robots[i * n // k:(i + 1) * n // k])}],
                 output="screen") for i in range(k)]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("robots", default_value="robot1",
                              description="robot namespaces, comma-separated"),
        DeclareLaunchArgument("processes", default_value="0",
                              description="monitor processes the robots are spread over "
                                          "(0: one per robot)"),
        DeclareLaunchArgument("params_file", default_value=str(PARAMS),
                              description="ROS 2 parameter file of the monitors"),
        OpaqueFunction(function=monitors),
    ])
