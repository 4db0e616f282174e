"""Make the vendored ROS 2 launch sources importable in the venv (run by scripts/setup.sh).

``launch``, ``launch_xml`` and ``launch_ros`` (ROS 2 Jazzy, pure Python, Apache-2.0) are not
on the package registry, so their sources are kept under ``third_party/`` (see
``third_party/README.md``) and put on the venv's path by a ``.pth`` file. ``launch_ros``
imports ``composition_interfaces`` (three service types, for composable-node containers):
its Python message module is generated here from the vendored ``.srv`` files with the
locked ROS 2 generators (``rosidl_adapter``, ``rosidl_generator_py``), into
``.venv/fd_monitor_third_party/``. Its C type support is not built: loading composable
nodes is the one part of launch_ros this cannot run (fd_monitor's launch files start
processes; the test suite parses them with launch's own parsers).

The same folder gets a ``.dist-info`` per vendored package (their entry points: launch finds
its XML parser and launch_ros' actions by them) and is an ament prefix holding launch's
``share/`` files (the substitution grammar). Idempotent: regenerates only when the ``.srv``
files are newer than the generated module, rewrites only what differs.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import site
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
THIRD = ROOT / "third_party"
#: The import roots of the vendored packages (each holds one package directory).
SOURCES = (THIRD / "launch" / "launch", THIRD / "launch" / "launch_xml",
           THIRD / "launch_ros" / "launch_ros")
PTH = "fd_monitor_third_party.pth"
#: What each vendored package's setup.py declares (version, entry points): launch finds its
#: XML parser and launch_ros' frontend actions through these entry points.
METADATA = {
    "launch": ("3.4.3", ""),
    "launch_xml": ("3.4.3", "[launch.frontend.parser]\nxml = launch_xml:Parser\n"),
    "launch_ros": ("0.26.6", "[launch.frontend.launch_extension]\nlaunch_ros = launch_ros\n"),
}


def generate_interfaces(out_root: Path) -> Path:
    """Generate ``composition_interfaces`` (Python only) under ``out_root``; its path."""
    from rosidl_adapter.srv import convert_srv_to_idl
    from rosidl_generator_py.generate_py_impl import generate_py

    src = THIRD / "composition_interfaces"
    dest = out_root / "composition_interfaces"
    srvs = sorted((src / "srv").glob("*.srv"))
    if dest.is_dir() and all((dest / "srv" / "__init__.py").stat().st_mtime
                             >= f.stat().st_mtime for f in srvs):
        return dest
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        (tmp / "idl" / "srv").mkdir(parents=True)
        with contextlib.redirect_stdout(io.StringIO()):       # one line per file otherwise
            for f in srvs:
                convert_srv_to_idl(src, "composition_interfaces", Path("srv") / f.name,
                                   tmp / "idl" / "srv")
            templates = Path(sys.prefix) / "share" / "rosidl_generator_py" / "resource"
            args = {"package_name": "composition_interfaces",
                    "output_dir": str(tmp / "out" / "composition_interfaces"),
                    "template_dir": str(templates),
                    "idl_tuples": [f"{tmp / 'idl'}:srv/{f.stem}.idl" for f in srvs],
                    "ros_interface_files": [str(f) for f in srvs],
                    "target_dependencies": []}
            (tmp / "args.json").write_text(json.dumps(args))
            generate_py(str(tmp / "args.json"), ["c"])
        gen = tmp / "out" / "composition_interfaces"
        for c_file in gen.rglob("*.c"):
            c_file.unlink()                                   # the C type support: not built
        (gen / "__init__.py").touch()
        if dest.exists():
            shutil.rmtree(dest)
        out_root.mkdir(parents=True, exist_ok=True)
        shutil.copytree(gen, dest)
    return dest


def write_metadata(out_root: Path) -> None:
    """A ``.dist-info`` per vendored package (name, version, entry points) beside the
    generated module: importlib.metadata finds them on the path."""
    for name, (version, entry_points) in METADATA.items():
        d = out_root / f"{name}-{version}.dist-info"
        d.mkdir(parents=True, exist_ok=True)
        meta = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"
        for fname, text in (("METADATA", meta), ("entry_points.txt", entry_points)):
            f = d / fname
            if not f.is_file() or f.read_text() != text:
                f.write_text(text)


def write_share(out_root: Path) -> None:
    """``out_root`` as an ament prefix holding what launch's setup.py installs under
    ``share/``: its package marker and the substitution grammar of the XML/YAML frontends
    (found through ``get_package_share_directory('launch')``, so ``AMENT_PREFIX_PATH`` must
    name ``out_root`` when a frontend file is parsed)."""
    marker = out_root / "share" / "ament_index" / "resource_index" / "packages" / "launch"
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.touch()
    grammar = out_root / "share" / "launch" / "frontend" / "grammar.lark"
    grammar.parent.mkdir(parents=True, exist_ok=True)
    src = THIRD / "launch" / "launch" / "share" / "launch" / "frontend" / "grammar.lark"
    if not grammar.is_file() or grammar.read_bytes() != src.read_bytes():
        shutil.copyfile(src, grammar)


def main() -> int:
    out_root = Path(sys.prefix) / "fd_monitor_third_party"
    generate_interfaces(out_root)
    write_metadata(out_root)
    write_share(out_root)
    paths = [*(str(p) for p in SOURCES), str(out_root)]
    pth = Path(site.getsitepackages()[0]) / PTH
    text = "\n".join(paths) + "\n"
    if not pth.is_file() or pth.read_text() != text:
        pth.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
