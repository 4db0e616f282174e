"""Where shipped configuration lives: plant files, scenarios, gain files, parameter files.

Looked up in this order: ``$FD_MONITOR_CONFIG``; the ``config/`` folder of a source checkout
(beside the package); ``<prefix>/share/fd_monitor/config`` of this Python's prefix (a pip
install); the same under every ``AMENT_PREFIX_PATH`` entry (a colcon workspace).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

__all__ = ["check_output", "config_dirs", "default_gain_path", "find_config_file",
           "path_for_file", "repo_root", "resolve_for_file"]


def repo_root() -> Path | None:
    """The source checkout holding this package, or None for an installed package."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "package.xml").is_file() and (root / "config").is_dir() else None


def config_dirs() -> list[Path]:
    """Candidate ``config/`` folders, most specific first (only those that exist)."""
    cands: list[Path] = []
    env = os.environ.get("FD_MONITOR_CONFIG")
    if env:
        cands.append(Path(env))
    root = repo_root()
    if root is not None:
        cands.append(root / "config")
    cands.append(Path(sys.prefix) / "share" / "fd_monitor" / "config")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            cands.append(Path(prefix) / "share" / "fd_monitor" / "config")
    seen: list[Path] = []
    for c in cands:
        if c.is_dir() and c not in seen:
            seen.append(c)
    return seen


def find_config_file(source: str | Path, kind: str, error: type[Exception],
                     what: str = "file") -> Path:
    """Resolve ``source``: an existing path, or a shipped name in ``config/<kind>/``.

    Parameters
    ----------
    source : str or pathlib.Path
        A path, or a bare name such as ``three_tank`` (``.yaml`` may be omitted).
    kind : str
        Sub-folder of ``config/``: ``systems``, ``scenarios``, ``gains``.
    error : type of Exception
        Raised, with a one-line message listing the shipped names, when nothing is found.
    what : str
        Word for the message (``plant``, ``scenario``...).
    """
    p = Path(source)
    if p.is_file():
        return p
    if p.exists():          # a folder, a FIFO...: its own message, not "not found"
        from fd_monitor.model.yaml_io import check_regular_file

        check_regular_file(p, error)
    looks_like_path = p.suffix in (".yaml", ".yml") or len(p.parts) > 1
    if not looks_like_path:
        for d in config_dirs():
            for cand in (d / kind / f"{p.name}.yaml", d / kind / f"{p.name}.yml"):
                if cand.is_file():
                    return cand
        known = sorted({f.stem for d in config_dirs() for f in (d / kind).glob("*.y*ml")
                        if not f.stem.endswith(".design")})
        raise error(f"{source}: unknown {what} (shipped: {', '.join(known) or 'none'}; "
                    f"or give a path to a YAML file)")
    raise error(f"{p}: file not found")


def default_gain_path(plant: str, method: str) -> Path:
    """Where a designer writes by default: ``config/gains/<plant>_<method>.yaml`` in a source
    checkout (so the shipped gain files are regenerated in place), else
    ``./<plant>_<method>.yaml``."""
    root = repo_root()
    name = f"{plant}_{method}.yaml"
    return root / "config" / "gains" / name if root is not None else Path(name)


def path_for_file(path: str | Path, anchor_file: str | Path) -> str:
    """How a file that refers to ``path`` stores it: relative to the folder of
    ``anchor_file`` (the gain file being written), with POSIX separators.

    A shipped gain file then names its design file ``../systems/f16xl.design.yaml``, which
    holds in the source checkout, in ``share/fd_monitor/config`` of an install and in a copy of
    the tree, and records no machine's folders. Paths on another drive (Windows), where no
    relative path exists, are stored absolute.

    Parameters
    ----------
    path : str or pathlib.Path
        The file referred to (absolute, or relative to the current folder).
    anchor_file : str or pathlib.Path
        The file that stores the reference (need not exist yet).

    Returns
    -------
    str
        E.g. ``../systems/f16xl.design.yaml``; read back with :func:`resolve_for_file`.
    """
    target = Path(os.path.abspath(path))
    base = Path(os.path.abspath(anchor_file)).parent
    try:
        rel = os.path.relpath(target, base)
    except ValueError:      # another drive: no relative path
        return target.as_posix()
    return Path(rel).as_posix()


def resolve_for_file(stored: str | Path, anchor_file: str | Path) -> Path:
    """The file a stored reference names: ``stored`` resolved against the folder of
    ``anchor_file`` (an absolute ``stored`` is returned as it is).

    Parameters
    ----------
    stored : str or pathlib.Path
        A value written by :func:`path_for_file` (POSIX separators).
    anchor_file : str or pathlib.Path
        The file that holds the reference.

    Returns
    -------
    pathlib.Path
        Normalised (``..`` folded), not checked for existence.
    """
    p = Path(str(stored))
    if p.is_absolute():
        return p
    return Path(os.path.normpath(Path(os.path.abspath(anchor_file)).parent / p))


def check_output(path: str | Path, what: str, error: type[Exception], *, folder: bool,
                 force: bool | None = None) -> Path:
    """Check, before a long computation, that its output can be written; one-line errors.

    Creates the missing parent folders (and the folder itself for ``folder=True``) and
    writes and removes a probe file there, so an unwritable place (a read-only mount, a
    path under a file, no permission — even for root) is refused now, not after minutes
    of computing.

    Parameters
    ----------
    path : str or pathlib.Path
    what : str
        The option, for the message (``"-o"``, ``"--report"``).
    error : type of Exception
    folder : bool
        True: ``path`` is a folder to write files into; False: a file to write.
    force : bool or None
        None: existing content may be overwritten (no check). False: refuse an existing
        file (``folder=False``) or a non-empty folder (``folder=True``); True: allow.
    """
    p = Path(path)
    if folder:
        if p.exists() and not p.is_dir():
            raise error(f"{what} {p}: exists and is not a folder")
        if force is False and p.is_dir() and any(p.iterdir()):
            raise error(f"{what} {p}: folder is not empty (would overwrite; use --force)")
        target = p
    else:
        if p.is_dir():
            raise error(f"{what} {p}: is a folder, expected a file name")
        if force is False and p.exists():
            raise error(f"{what} {p}: exists (would overwrite; use --force)")
        target = p.parent
    try:
        target.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=target, prefix=".fd_monitor_probe_"):
            pass
    except OSError as exc:
        raise error(f"{what} {p}: cannot write there: {exc.strerror or exc}") from None
    return p
