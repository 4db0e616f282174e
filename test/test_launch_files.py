"""The launch files, loaded by ROS 2 launch's own parsers (the vendored Jazzy ``launch``,
``launch_xml`` and ``launch_ros``: third_party/, put on the path by scripts/setup.sh).

Each file is parsed into a LaunchDescription, its arguments and substitutions evaluated in a
LaunchContext as ``ros2 launch`` would, and its launch_ros ``Node`` actions checked (package,
executable, node name, namespace, parameter file), without starting processes. The
parameters each node would get are read by rcl itself: an rclpy context with the node's
``__ns`` and ``--params-file`` and a node of that name (a ``monitor:`` key would not match
``/robot1/monitor``: only ``/**/monitor`` does).
"""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
LAUNCH = REPO / "launch"

pytestmark = pytest.mark.ros

launch = pytest.importorskip("launch", reason="the vendored launch sources: bash scripts/setup.sh")
launch_ros = pytest.importorskip("launch_ros")


def description(path: Path):
    """The LaunchDescription of a .launch.py or .launch.xml file, by launch's own loaders."""
    if path.suffix == ".py":
        from launch.launch_description_sources import (
            get_launch_description_from_python_launch_file,
        )

        return get_launch_description_from_python_launch_file(str(path))
    from launch.frontend import Parser

    root, parser = Parser.load(str(path))
    return parser.parse_description(root)


@pytest.fixture(autouse=True)
def ament_prefix(monkeypatch):
    """launch's own share/ files (its frontend grammar) are found through the ament index:
    scripts/third_party.py installs them in this prefix."""
    import os
    import sys

    prefix = Path(sys.prefix) / "fd_monitor_third_party"
    old = os.environ.get("AMENT_PREFIX_PATH")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix) + (os.pathsep + old if old else ""))


def nodes(path: Path, **arguments: str) -> list:
    """The launch_ros Node actions of a launch file with ``arguments``, their substitutions
    performed (what ``ros2 launch`` evaluates before it starts the processes)."""
    from launch import LaunchContext
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    ctx = LaunchContext()
    # what IncludeLaunchDescription sets for the file it includes ($(dirname))
    ctx.extend_locals({"current_launch_file_path": str(path),
                       "current_launch_file_directory": str(path.parent)})
    ctx.launch_configurations.update(arguments)
    out = []

    def walk(entities):
        for e in entities:
            if isinstance(e, launch_ros.actions.Node):
                e._perform_substitutions(ctx)        # what Node.execute does first
                out.append(e)
            elif isinstance(e, (DeclareLaunchArgument, OpaqueFunction)):
                walk(e.visit(ctx) or [])
            else:
                raise AssertionError(f"{path.name}: unexpected action {type(e).__name__}")
    walk(description(path).entities)
    return out


def text(value) -> str:
    """A Node's package or executable as text (the XML frontend keeps substitutions)."""
    from launch import LaunchContext
    from launch.utilities import perform_substitutions

    return value if isinstance(value, str) else perform_substitutions(LaunchContext(), value)


def params_file(node) -> str:
    """The one parameter file a node is given."""
    files = [p for p, is_file in node._Node__expanded_parameter_arguments if is_file]
    assert len(files) == 1, files
    return files[0]


def parameters_seen(nodes_: list) -> list[dict]:
    """The parameters rcl gives each launched node (its name, namespace and parameter file;
    an rclpy context of its own each)."""
    from ros_util import ros_context

    out: list[dict] = []
    for n in nodes_:
        with ros_context(["x", "--ros-args", "--params-file", params_file(n)]) as ctx:
            from rclpy.node import Node

            node = Node(n.node_name.rsplit("/", 1)[1], namespace=n.expanded_node_namespace,
                        context=ctx, automatically_declare_parameters_from_overrides=True)
            out.append({p.name: p.value for p in node._parameters.values()})
            node.destroy_node()
    return out


@pytest.mark.parametrize("suffix", [".launch.py", ".launch.xml"])
def test_monitor_launch_one_monitor_per_robot_namespace(suffix):
    path = LAUNCH / f"monitor{suffix}"
    if suffix == ".launch.py":
        got = nodes(path, robots="robot1, robot2")
        assert [n.node_name for n in got] == ["/robot1/monitor", "/robot2/monitor"]
    else:
        got = nodes(path, namespace="robot2")
        assert [n.node_name for n in got] == ["/robot2/monitor"]
    for n, seen in zip(got, parameters_seen(got)):
        assert (text(n.node_package), text(n.node_executable)) == ("fd_monitor", "monitor")
        assert Path(params_file(n)).resolve() == REPO / "config" / "launch" / "monitor.yaml"
        assert seen["system"] == "three_tank" and seen["gains"] == "three_tank_thresholds"
        assert seen["layout"] == "fused" and seen["fault_clear_after"] == 5.0
    # the default: one robot
    assert [n.node_name for n in nodes(path)] == ["/robot1/monitor"]


def test_monitor_launch_spreads_robots_over_processes():
    """``processes:=2``: five robots in two ``monitor`` processes (two and three robots, in
    order), each given the shipped parameter file and its share as ``robots``; rcl gives
    every hosted robot's node (``/r3/monitor``) the shipped parameters."""
    from ros_util import ros_context

    from fd_monitor.nodes.robots import robot_namespaces

    got = nodes(LAUNCH / "monitor.launch.py", robots="r0, r1, r2, r3, r4", processes="2")
    assert len(got) == 2
    hosted = []
    for n in got:
        assert (text(n.node_package), text(n.node_executable)) == ("fd_monitor", "monitor")
        files = [p for p, is_file in n._Node__expanded_parameter_arguments if is_file]
        assert Path(files[0]).resolve() == REPO / "config" / "launch" / "monitor.yaml"
        with ros_context(["x", "--ros-args", *(a for f in files
                                                for a in ("--params-file", f))]) as ctx:
            from rclpy.node import Node

            peek = Node("monitor", context=ctx, allow_undeclared_parameters=True,
                        automatically_declare_parameters_from_overrides=True)
            spaces = robot_namespaces(None, peek.get_parameter("robots").value)
            hosted.append(spaces)
            robot = Node("monitor", namespace=spaces[-1], context=ctx,
                         automatically_declare_parameters_from_overrides=True)
            seen = {p.name: p.value for p in robot._parameters.values()}
            assert seen["gains"] == "three_tank_thresholds" and seen["fault_clear_after"] == 5.0
            for x in (peek, robot):
                x.destroy_node()
    assert hosted == [["/r0", "/r1"], ["/r2", "/r3", "/r4"]]
    # processes:=0 (the default): a process per robot, as before
    assert len(nodes(LAUNCH / "monitor.launch.py", robots="r0, r1, r2")) == 3


@pytest.mark.parametrize("suffix", [".launch.py", ".launch.xml"])
def test_chain_launch_four_nodes_in_one_namespace(suffix):
    got = nodes(LAUNCH / f"chain{suffix}", namespace="r7")
    names = ["observer", "detector", "agei", "bias_estimator"]
    assert [n.node_name for n in got] == [f"/r7/{x}" for x in names]
    assert [text(n.node_executable) for n in got] == names
    assert {text(n.node_package) for n in got} == {"fd_monitor"}
    for x, seen in zip(names, parameters_seen(got)):
        assert seen["system"] == "three_tank" and seen["gains"] == "three_tank_thresholds"
        assert "layout" not in seen                  # the detector is one node anyway
        assert ("fault_clear_after" in seen) == (x == "bias_estimator")


def test_launch_files_are_installed_for_colcon():
    """setup.py's data files put launch/ and config/launch/ under share/fd_monitor/."""
    text = (REPO / "setup.py").read_text()
    assert 'data_tree("launch", f"share/{package_name}/launch")' in text
    assert sorted(p.name for p in LAUNCH.iterdir()) == [
        "chain.launch.py", "chain.launch.xml", "monitor.launch.py", "monitor.launch.xml"]
