"""Compare the running environment with requirements.lock (stdlib only: runs in a bare venv).

    python scripts/lockcheck.py            exit 1 and name every difference
    python scripts/lockcheck.py --extras   print the installed packages the lock does not name

scripts/setup.sh calls it to decide whether to (re)install the lock and to remove what the
lock no longer holds; test/test_lock.py imports it to read the lock.
"""

from __future__ import annotations

import importlib.metadata as md
import re
import site
import sys
from pathlib import Path

LOCK = Path(__file__).resolve().parent.parent / "requirements.lock"
#: The project itself: installed editable from the checkout, never from the lock.
SELF = "fd-monitor"

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)\s*(?:;([^\\]*))?")


def normalize(name: str) -> str:
    """PEP 503 name: ``ros_jazzy.rclpy`` and ``ROS-Jazzy-rclpy`` are one package."""
    return re.sub(r"[-_.]+", "-", name).lower()


def read_lock(path: Path = LOCK) -> dict[str, list[tuple[str, str | None, list[str]]]]:
    """Pins of a ``uv pip compile --generate-hashes`` file.

    Returns
    -------
    dict
        Normalized name -> list of (version, environment marker or None, sha256 hashes); a
        universal lock may pin one name twice, under exclusive markers (per Python version).
    """
    out: dict[str, list[tuple[str, str | None, list[str]]]] = {}
    current: list[str] | None = None
    for line in path.read_text(encoding="utf-8").splitlines():
        m = _PIN.match(line)
        if m:
            current = []
            marker = m.group(3).strip() if m.group(3) else None
            out.setdefault(normalize(m.group(1)), []).append((m.group(2), marker, current))
        elif current is not None and "--hash=sha256:" in line:
            current.append(line.split("--hash=sha256:")[1].split()[0])
    return out


def _marker_holds(marker: str | None) -> bool:
    if not marker:
        return True
    try:
        from packaging.markers import Marker
    except ImportError:                      # a bare venv: pip's own copy of packaging
        from pip._vendor.packaging.markers import Marker
    return bool(Marker(marker).evaluate())


def pins_here(lock: dict[str, list[tuple[str, str | None, list[str]]]]) -> dict[str, str]:
    """Name -> version of the pins whose markers hold for this interpreter and platform."""
    return {name: v for name, pins in lock.items() for v, mk, _ in pins if _marker_holds(mk)}


def installed() -> dict[str, str]:
    """Name -> version of every package an installer put in this environment.

    Only distributions with an ``INSTALLER`` record count: the ROS wheels also carry the
    ``*.egg-info`` of the ROS packages they bundle (``rclpy``, ``std_msgs``, ...), which no
    installer placed and no lock names. Only site-packages is read: setuptools puts its
    vendored copies (packaging, zipp, ...) on ``sys.path`` once imported.
    """
    out = {}
    for d in md.distributions(path=site.getsitepackages()):
        if d.read_text("INSTALLER") is not None:
            out[normalize(d.metadata["Name"])] = d.version
    out.pop(SELF, None)
    return out


def differences() -> tuple[list[str], list[str]]:
    """(problems, extras): pins missing or at another version, and packages not locked."""
    lock = read_lock()
    want, have = pins_here(lock), installed()
    problems = [f"{n}=={v} is locked, {'not installed' if n not in have else have[n]}"
                for n, v in sorted(want.items()) if have.get(n) != v]
    extras = sorted(n for n in have if n not in lock)
    problems += [f"{n} {have[n]} is installed but not locked" for n in extras]
    return problems, extras


def main(argv: list[str]) -> int:
    problems, extras = differences()
    if "--extras" in argv:
        print("\n".join(extras))
        return 0
    for p in problems:
        print(f"lockcheck: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
