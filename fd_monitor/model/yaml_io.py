"""The one YAML reader of every fd_monitor file, and the memory guard of large requests.

Plants, scenarios, gain files, design files and the bag library are read by
:func:`read_yaml` (strict: UTF-8, no duplicate keys, bounded nesting and alias expansion);
:func:`require_memory` refuses, before allocating, arrays that would not fit in memory.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import yaml

from fd_monitor.model.errors import SystemFileError

__all__ = ["MAX_FILE_BYTES", "MAX_YAML_ALIASES", "MAX_YAML_DEPTH", "MAX_YAML_NODES",
           "PLAIN_TAGS", "check_regular_file", "parse_yaml_text", "read_yaml",
           "require_memory"]

#: Largest YAML file read, bytes (the largest shipped file is ~20 kB; a 500-state plant, the
#: largest any designer takes, ~3 MB). Checked from the file's size before it is read: a
#: 100 MB file would take gigabytes as YAML nodes.
MAX_FILE_BYTES = 16 * 1024 * 1024
#: The only explicit YAML tags accepted: the core schema's plain scalars, sequences and
#: mappings. ``!!binary``, ``!!timestamp``, ``!!set``, ``!!python/...`` and local ``!tags``
#: are refused (no file of the project needs them; each reads as something else).
PLAIN_TAGS = frozenset(f"tag:yaml.org,2002:{t}" for t in
                       ("str", "int", "float", "bool", "null", "seq", "map"))

#: Limits of the strict YAML reader (:func:`read_yaml`): nesting depth, alias uses, and
#: nodes after alias expansion (a 500x500 plant is 250,000 nodes per matrix). Beyond them a
#: file is refused before it is built (a deep nesting overflows the recursive builder, an
#: alias bomb expands into gigabytes when printed).
MAX_YAML_DEPTH = 64
MAX_YAML_ALIASES = 1000
MAX_YAML_NODES = 20_000_000


# libyaml's parser when PyYAML has it (5-10x faster on gain files); same events and marks.
_BaseLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _StrictLoader(_BaseLoader):
    """yaml.SafeLoader that refuses duplicate keys (YAML 1.2; PyYAML keeps the last one).

    Merge keys (``<<: *base``) stay allowed: explicit keys override merged ones, as YAML
    defines; only two explicit equal keys in one mapping are refused.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> Any:
        seen: dict[tuple[str, str], int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node,
                                                                           yaml.ScalarNode):
                continue
            key = (key_node.tag, key_node.value)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key_node.value!r} (first at line "
                    f"{seen[key]})", key_node.start_mark)
            seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


# A date reads as the text it is (YAML 1.1's implicit timestamps would make a datetime of
# `2024-01-01`, which no schema of the project takes and every message would misname).
_StrictLoader.yaml_implicit_resolvers = {
    ch: [(tag, rx) for tag, rx in rs if tag != "tag:yaml.org,2002:timestamp"]
    for ch, rs in _BaseLoader.yaml_implicit_resolvers.items()}

# YAML 1.2 floats (1e-300, 1.0e12, 5E3): YAML 1.1, which PyYAML implements, reads them as
# strings, and "expected a number, got '1e-300'" puzzles everyone. Integers keep their own
# resolver (it comes first); this one needs a dot or an exponent.
_StrictLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def _check_structure(text: str, origin: str, error: type[Exception]) -> None:
    """Refuse, from the event stream (no recursion, nothing built), a YAML document nested
    deeper than MAX_YAML_DEPTH, using more than MAX_YAML_ALIASES aliases, or expanding to
    more than MAX_YAML_NODES nodes."""
    depth, aliases = 0, 0
    sizes: dict[str, int] = {}            # anchor -> nodes of the anchored node, expanded
    stack: list[list[Any]] = [[0, None]]  # per open collection: [nodes so far, anchor]
    for ev in yaml.parse(text, Loader=_BaseLoader):
        line = ev.start_mark.line + 1 if ev.start_mark is not None else 0
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            _check_tag(ev, origin, line, error)
            depth += 1
            if depth > MAX_YAML_DEPTH:
                raise error(f"{origin}: line {line}: YAML nested deeper than "
                            f"{MAX_YAML_DEPTH} levels (refused)")
            stack.append([1, ev.anchor])
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
            count, anchor = stack.pop()
            if anchor is not None:
                sizes[anchor] = count
            stack[-1][0] += count
        elif isinstance(ev, yaml.ScalarEvent):
            _check_tag(ev, origin, line, error)
            if ev.anchor is not None:
                sizes[ev.anchor] = 1
            stack[-1][0] += 1
        elif isinstance(ev, yaml.AliasEvent):
            aliases += 1
            if aliases > MAX_YAML_ALIASES:
                raise error(f"{origin}: line {line}: more than {MAX_YAML_ALIASES} YAML "
                            f"aliases (refused)")
            stack[-1][0] += sizes.get(ev.anchor or "", 1)
            total = sum(c for c, _ in stack)
            if total > MAX_YAML_NODES:
                raise error(f"{origin}: line {line}: YAML aliases expand to more than "
                            f"{MAX_YAML_NODES} nodes (an alias bomb? refused)")


def _check_tag(ev: Any, origin: str, line: int, error: type[Exception]) -> None:
    """Refuse an explicit tag outside :data:`PLAIN_TAGS`."""
    tag = ev.tag
    if tag is None or tag == "!":      # untagged, or quoted ("!": non-specific)
        return
    if tag not in PLAIN_TAGS:
        short = tag.replace("tag:yaml.org,2002:", "!!")
        raise error(f"{origin}: line {line}: YAML tag {short[:60]} (refused: only plain "
                    f"scalars, sequences and mappings)")


def check_regular_file(path: Path, error: type[Exception], what: str = "file") -> None:
    """Refuse, before opening it, a path that is missing, a folder, a FIFO or another special
    file (opening a FIFO would block), or larger than :data:`MAX_FILE_BYTES`."""
    import stat

    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else "a special file"
        raise error(f"{path}: is {kind}, not a regular {what}")
    if st.st_size > MAX_FILE_BYTES:
        raise error(f"{path}: {st.st_size / 1e6:.3g} MB, over the limit of "
                    f"{MAX_FILE_BYTES / 1e6:.3g} MB for a YAML file (MAX_FILE_BYTES; refused "
                    f"before reading)")


def read_yaml(path: Path, error: type[Exception] = SystemFileError) -> Any:
    """Read a YAML file strictly; raise ``error`` with a one-line message on any failure.

    The one YAML reader of every fd_monitor file (plants, scenarios, gain files, design
    files, the bag library): UTF-8 only; duplicate keys, nesting deeper than
    :data:`MAX_YAML_DEPTH`, more than :data:`MAX_YAML_ALIASES` aliases or an alias expansion
    beyond :data:`MAX_YAML_NODES` nodes are refused.
    """
    check_regular_file(Path(path), error)
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    return parse_yaml_text(raw, str(path), error)


def parse_yaml_text(raw: bytes | str, origin: str, error: type[Exception] = SystemFileError
                    ) -> Any:
    """:func:`read_yaml` on bytes or text already read (``origin`` names it in messages)."""
    if isinstance(raw, bytes):
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise error(f"{origin}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                        f"{exc.start})") from None
    else:
        text = raw
    if len(text) > MAX_FILE_BYTES:
        raise error(f"{origin}: {len(text) / 1e6:.3g} MB of text, over the limit of "
                    f"{MAX_FILE_BYTES / 1e6:.3g} MB for a YAML file (MAX_FILE_BYTES)")
    # the meaning never depends on a byte-order mark or the line endings
    text = text.removeprefix("\ufeff").replace("\r\n", "\n")
    try:
        _check_structure(text, origin, error)
        return yaml.load(text, Loader=_StrictLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{origin}: invalid YAML{where}: {problem}") from None
    except RecursionError:
        raise error(f"{origin}: YAML nested too deeply (refused)") from None


def require_memory(nbytes: float, what: str, error: type[Exception]) -> None:
    """Refuse, before allocating, arrays of ``nbytes`` bytes that would not fit in memory.

    Parameters
    ----------
    nbytes : float
        Bytes the computation would allocate (an estimate from the shapes).
    what : str
        What needs them, with where it comes from (``"scenario x.yaml: 1e12 samples"``).
    error : type of Exception
        Raised with the size needed and the memory available.
    """
    avail = _available_memory()
    if not math.isfinite(nbytes) or nbytes > avail:
        raise error(f"{what}: would need {_human(nbytes)} of memory, "
                    f"{_human(avail)} available (refused before allocating)")


def _available_memory() -> float:
    """Bytes of memory available now (MemAvailable), else physical memory."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError):
        return 8.0e9


def _human(nbytes: float) -> str:
    if not math.isfinite(nbytes):
        return "unbounded bytes"
    for unit, f in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if nbytes >= f:
            return f"{nbytes / f:.3g} {unit}"
    return f"{nbytes:.0f} bytes"
