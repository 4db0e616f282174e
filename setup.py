"""ament_python package fd_monitor; also installs with pip into a virtualenv.

Console scripts go to ``bin/`` for pip installs; colcon installs them to
``lib/fd_monitor/`` through setup.cfg. The same programs are also shipped as launchers in
``lib/fd_monitor/`` (data files), so ``ros2 run fd_monitor <exe>`` finds them in a pip
prefix too.
"""

from pathlib import Path

from setuptools import find_packages, setup

package_name = "fd_monitor"
here = Path(__file__).resolve().parent

# Executables: name -> module with main(). One table (fd_monitor/commands/executables.py, read here
# without importing the package) feeds the console scripts, the launchers under
# lib/fd_monitor/ and `python -m fd_monitor run <node>`.
_ns: dict = {}
exec((here / "fd_monitor" / "commands" / "executables.py").read_text(), _ns)
EXECUTABLES: dict[str, str] = _ns["EXECUTABLES"]


# Dependencies with a rosdep key are in package.xml too (test/test_packaging.py compares);
# the others are listed once, in requirements.txt (pip, in a ROS 2 workspace).
PIP_ONLY = [ln.strip() for ln in (here / "requirements.txt").read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]


def data_tree(src: str, dest: str) -> list[tuple[str, list[str]]]:
    """(install dir, files) pairs for every file below ``src``, kept in the same layout."""
    out: dict[str, list[str]] = {}
    for p in sorted((here / src).rglob("*")):
        if p.is_file() and "__pycache__" not in p.parts:
            rel = p.relative_to(here)
            out.setdefault(str(Path(dest) / rel.parent.relative_to(src)), []).append(str(rel))
    return sorted(out.items())


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "benchmarks"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "requirements.txt"]),
        ("lib/" + package_name, sorted(f"launchers/{n}" for n in EXECUTABLES)),
        *data_tree("config", f"share/{package_name}/config"),
        *data_tree("bags", f"share/{package_name}/bags"),
        *data_tree("launch", f"share/{package_name}/launch"),
    ],
    install_requires=[
        "setuptools",
        "numpy",
        "scipy",
        "pyyaml",
        "matplotlib",
        *PIP_ONLY,
    ],
    extras_require={
        "ros": [
            "ros-jazzy-rclpy",
            "ros-jazzy-std-msgs",
            "ros-jazzy-diagnostic-msgs",
            "ros-jazzy-rmw-fastrtps-cpp",
            "ros-jazzy-rcl-interfaces",
            "ros-jazzy-lifecycle-msgs",
            "ros-jazzy-std-srvs",
            "ros-jazzy-sensor-msgs",
            "ros-jazzy-nav-msgs",
            "ros-jazzy-geometry-msgs",
        ],
        "dev": ["pytest", "hypothesis", "ruff", "mypy", "types-PyYAML", "setuptools>=70", "wheel",
                "colcon-core", "colcon-ros", "colcon-python-setup-py", "colcon-bash",
                "sphinx", "myst-parser", "pytest-xdist", "osrf-pycommon"],
    },
    zip_safe=True,
    maintainer="fd_monitor developers",
    maintainer_email="fd-monitor@example.com",
    description="Model-based fault detection for ROS 2 plants and robots",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{n} = {m}:main" for n, m in EXECUTABLES.items()],
    },
)
