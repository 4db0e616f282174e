"""The sensor-bias chain as four processes (observer, detector, agei, bias_estimator) in one
namespace: the distributed form of the ``thresholds`` method.

    ros2 launch fd_monitor chain.launch.py namespace:=robot1

Every node's ``~/reset`` starts a new run of the whole chain; the bias_estimator publishes the
fault verdict on ``fd/fault``. Parameters: ``config/launch/chain.yaml``.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

#: config/launch/ beside launch/ (the source tree and share/fd_monitor/ alike)
PARAMS = Path(__file__).resolve().parent.parent / "config" / "launch" / "chain.yaml"

#: The chain's nodes, each its own executable.
NODES = ("observer", "detector", "agei", "bias_estimator")


def generate_launch_description():
    ns, params = LaunchConfiguration("namespace"), LaunchConfiguration("params_file")
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="robot1",
                              description="the robot's namespace"),
        DeclareLaunchArgument("params_file", default_value=str(PARAMS),
                              description="ROS 2 parameter file of the chain"),
        *(Node(package="fd_monitor", executable=n, name=n, namespace=ns,
               parameters=[params], output="screen") for n in NODES),
    ])
