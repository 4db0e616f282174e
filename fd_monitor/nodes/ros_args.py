"""ROS arguments of the node executables: ``--params-file`` found and checked before rcl sees it.

rcl reads ``--ros-args --params-file FILE`` inside ``rclpy.init``: a missing file ends in an
``RCLError`` traceback, and a file that is not UTF-8 makes its YAML parser loop for ever. So
every ``--params-file`` is resolved and read here first:

- a path that exists (relative to the current directory, or absolute) is used as given;
- a relative path that does not exist is looked up in the shipped ``config/`` folders
  (:func:`fd_monitor.model.paths.config_dirs`: the source checkout, ``share/fd_monitor/config`` of a
  pip or colcon install), with a leading ``config/`` dropped, so the command printed by
  ``--help`` (``--params-file config/detector.yaml``) works from any directory, e.g. the
  root of a colcon workspace;
- the file must be UTF-8 YAML with a mapping at the top (node name -> ``ros__parameters``).

Anything else is one line (:class:`~fd_monitor.model.errors.FdMonitorError`); the executable prints
``<prog>: error: ...`` and exits with status 2.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import rclpy
from rclpy.exceptions import InvalidNamespaceException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.validate_namespace import validate_namespace

from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.paths import config_dirs
from fd_monitor.model.yaml_io import check_regular_file, read_yaml

__all__ = ["find_params_file", "init_ros", "resolve_params_files", "shown_params_file",
           "take_namespace", "take_node_name"]

#: The remap rules that rename a node (``__name`` is the older spelling rcl still reads).
_NODE_REMAPS = ("__node:=", "__name:=")
#: The remap rule that moves a node to another namespace.
_NS_REMAPS = ("__ns:=",)
#: ROS options whose value is the next argument (rcl's arguments.c): a value is never read
#: as an option.
_WITH_VALUE = frozenset(("--params-file", "-r", "--remap", "-p", "--param", "-e", "--enclave",
                         "--log-level", "--log-config-file", "--log-file-name"))


def find_params_file(name: str) -> Path:
    """The parameter file ``name`` refers to (see the module docstring); checked readable.

    Raises
    ------
    FdMonitorError
        Not found (naming where it was looked for), not UTF-8, not YAML, or not a mapping.
    """
    p = Path(name)
    found: Path | None = p if p.is_file() else None
    dirs = config_dirs()
    if found is None and not p.is_absolute():
        rel = Path(*p.parts[1:]) if len(p.parts) > 1 and p.parts[0] == "config" else p
        found = next((d / rel for d in dirs if (d / rel).is_file()), None)
    if found is None and p.exists():       # a folder, a FIFO: say so, not "not found"
        check_regular_file(p, FdMonitorError, "parameter file")
    if found is None:
        where = "" if p.is_absolute() else (
            f" (looked in {Path.cwd()}" + "".join(f", {d}" for d in dirs) + ")")
        raise FdMonitorError(f"--params-file {name}: file not found{where}")
    data = read_yaml(found, FdMonitorError)
    if not isinstance(data, dict):
        raise FdMonitorError(f"{found}: not a ROS 2 parameter file: expected a mapping "
                             f"'<node name>: {{ros__parameters: {{...}}}}' at the top, got "
                             f"{type(data).__name__}")
    _check_params_tree(found, data, "")
    return found


def _check_params_tree(path: Path, tree: dict, where: str) -> None:
    """Every key of a parameter file is a node or namespace name whose mapping leads to
    ``ros__parameters`` (a mapping): what rcl accepts, refused here in one line before rcl
    prints its own multi-line parse error."""
    for key, value in tree.items():
        at = f"{where}{key}"
        if key == "ros__parameters":
            if not isinstance(value, dict):
                raise FdMonitorError(f"{path}: {at}: expected a mapping of parameters, got "
                                     f"{type(value).__name__}")
            continue
        if not isinstance(value, dict) or not value:
            raise FdMonitorError(
                f"{path}: {at}: not inside ros__parameters (expected '<node name>: "
                f"{{ros__parameters: {{name: value, ...}}}}'; got {type(value).__name__} "
                f"{str(value)[:40]!r})")
        _check_params_tree(path, value, f"{at}.")


def _ros_option_pairs(args: Sequence[str]) -> Iterator[tuple[int, str, str | None]]:
    """``(i, option, value)`` for every option inside ``--ros-args`` (up to a ``--``): the
    one walk of the ROS arguments; ``value`` is the next argument (None: none), which the
    caller may take (the walk does not look inside values)."""
    in_ros = False
    i = 0
    while i < len(args):
        a = args[i]
        if a == "--ros-args":
            in_ros = True
        elif a == "--":
            in_ros = False
        elif in_ros:
            value = args[i + 1] if i + 1 < len(args) else None
            yield i, a, value
            if a in _WITH_VALUE:
                i += 1
        i += 1


def resolve_params_files(args: Sequence[str]) -> list[str]:
    """``args`` with every ``--params-file`` inside ``--ros-args`` resolved and checked."""
    out = list(args)
    for i, opt, value in _ros_option_pairs(out):
        if opt == "--params-file":
            if value is None:
                raise FdMonitorError("--params-file: expected a file name after it")
            out[i + 1] = str(find_params_file(value))
    return out


def _take_remap(args: Sequence[str], rules: tuple[str, ...]) -> tuple[list[str], str | None]:
    """``args`` without the global remap rules starting with one of ``rules``, and the
    value of the last one (None: none)."""
    argv = list(args)
    drop: set[int] = set()
    value_of: str | None = None
    for i, opt, value in _ros_option_pairs(argv):
        if opt in ("-r", "--remap") and value is not None and value.startswith(rules):
            value_of = value.split(":=", 1)[1]
            drop.update((i, i + 1))
    # "--ros-args" left empty is still valid for rcl
    return [a for i, a in enumerate(argv) if i not in drop], value_of


def take_node_name(args: Sequence[str]) -> tuple[list[str], str | None]:
    """``args`` without the node-name remap rules (``--ros-args -r __node:=NAME``, what
    launch_ros' ``Node(name=...)`` passes), and the last NAME given (None: none).

    rcl applies such a rule to every node of the process, so an executable running several
    nodes (``monitor`` with ``layout:=nodes``) takes it out and names its nodes from it
    instead (``det1_observer``, ``det1_detector``, ...): four nodes
    called ``det1`` would make rcl warn "Publisher already registered" and collide in the
    graph. A rule for one node only (``observer:__node:=x``) is left to rcl.
    """
    return _take_remap(args, _NODE_REMAPS)


def take_namespace(args: Sequence[str]) -> tuple[list[str], str | None]:
    """``args`` without the namespace remap rules (``--ros-args -r __ns:=/NS``, what
    launch_ros' ``Node(namespace=...)`` passes), and the last NS given (None: none).

    rcl applies such a rule to every node of the process, whatever namespace the node was
    created with, so an executable hosting several robots' nodes (``monitor`` with
    ``robots``: ``/NS/robot1/monitor``, ``/NS/robot2/monitor``) takes it out and gives each
    node its namespace itself. A value rcl would refuse (not absolute, not a valid
    namespace) is left in place for rcl to report; a rule for one node only
    (``monitor:__ns:=/x``) is left to rcl.
    """
    rest, ns = _take_remap(args, _NS_REMAPS)
    if ns is None:
        return list(args), None
    try:
        validate_namespace(ns)
    except InvalidNamespaceException:
        return list(args), None
    return rest, ns


def init_ros(args: Sequence[str] | None = None) -> None:
    """``rclpy.init`` on ``args`` (default ``sys.argv``) with checked ``--params-file``.

    Raises
    ------
    FdMonitorError
        A bad ``--params-file``, or any ROS argument rcl refuses (its message, first part).
    """
    argv = resolve_params_files(sys.argv if args is None else args)
    try:
        rclpy.init(args=argv)
    except _rclpy.RCLError as exc:
        # rcl appends ", at <source file>:<line>" frames: keep the message only.
        msg = str(exc).split(", at /")[0].replace("\n", " ")
        raise FdMonitorError(f"bad ROS arguments: {msg}") from None


def shown_params_file(stem: str) -> str:
    """The parameter file ``config/<stem>.yaml`` as ``--help`` shows it.

    ``config/<stem>.yaml`` when that path works from the current directory (a source
    checkout), else the installed file (e.g. ``<ws>/install/fd_monitor/share/fd_monitor/
    config/detector.yaml``), else ``config/<stem>.yaml``.
    """
    rel = Path("config") / f"{stem}.yaml"
    if rel.is_file():
        return str(rel)
    for d in config_dirs():
        if (d / rel.name).is_file():
            return str(d / rel.name)
    return str(rel)
