"""Gain files: what a designer writes and what the runtime loads, re-checks and runs.

A gain file is YAML with human-readable matrices (nested lists)::

    format_version: 1
    method: qb                       # qb | thresholds | hinf_sc | hminus_switched
    system: {name: pwa_cascade, sha256: <hex of the plant's canonical form>}
                                     # + file: ../motor.yaml for a plant not found by its name
    created: 2026-11-22T10:00:00Z
    solver: {name: CLARABEL, status: optimal, time_s: 0.012}
    parameters: {...}                # the design parameters
    results: {...}                   # gains per mode, P, thresholds, ...
    certificate: {...}               # what the loader re-verifies (LMI margins, eigenvalues)
    digest: {sha256: ..., parts: {key path: ...}}   # covers every key above

A gain file for another plant (a different SHA-256) is refused. A plant that cannot be found
by its name (not a shipped one: an identified or hand-written plant file elsewhere) is
recorded by path as ``system.file``, and the plant is found from it
(:func:`fd_monitor.model.system.gain_system`): like every path stored in a gain file,
relative to the gain file's own folder with POSIX separators, resolved against it when read
(:func:`~fd_monitor.model.paths.path_for_file`,
:func:`~fd_monitor.model.paths.resolve_for_file`). The certificate is checked
by the method's ``check_certificate(system, gains)`` in ``fd_monitor.core`` (numpy only), so
the runtime trusts nothing it cannot recompute. What cannot be recomputed from the plant
(estimator, AGEI and isolation parameters, design parameters, solver figures, ...) is covered
by the ``digest`` the designer writes: a SHA-256 of the canonical form of every other key,
plus a short digest per key path, so that an edit anywhere is refused with the key path that
changed. The digest detects edits and bit rot; it is not a signature (anyone can re-run the
writer), so a file is trusted as far as its origin is.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import importlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fd_monitor.model.errors import GainFileError
from fd_monitor.model.paths import find_config_file, path_for_file, resolve_for_file
from fd_monitor.model.system import System
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["GainFile", "CERTIFICATE_CHECKS", "check_digest", "gain_digest", "gains_from_doc",
           "load_gains",
           "save_gains", "to_plain", "from_plain", "write_gain_doc"]

FORMAT_VERSION = 1

#: method -> "module:function" that raises GainFileError when the certificate fails.
CERTIFICATE_CHECKS: dict[str, str] = {
    "qb": "fd_monitor.core.qb_certificate:check_certificate",
    "thresholds": "fd_monitor.core.thresholds:check_certificate",
    "hinf_sc": "fd_monitor.core.hinf_certificate:check_certificate",
    "hminus_switched": "fd_monitor.core.generalized_observer:check_certificate",
}


@dataclass(frozen=True)
class GainFile:
    """A loaded gain file.

    Attributes
    ----------
    path : str
    method : str
    system_name, system_sha256 : str
    created : str
    solver : dict
    parameters : dict
    results : dict
        Matrices and vectors as numpy arrays, scalars as floats.
    certificate : dict
    system_file : str
        The plant file the gain file records (``system.file``), resolved against the gain
        file's folder; ``""`` when it records none (a plant found by its name).
    certificate_status : str
        ``verified`` once ``load_gains`` re-checked it, ``unchecked`` otherwise.
    """

    path: str
    method: str
    system_name: str
    system_sha256: str
    created: str
    solver: Mapping[str, Any]
    parameters: Mapping[str, Any]
    results: Mapping[str, Any]
    certificate: Mapping[str, Any]
    system_file: str = ""
    certificate_status: str = "unchecked"

    @property
    def design_file(self) -> Path | None:
        """The design file the gains were made from (``parameters.design_file``, stored
        relative to the gain file's folder), or None when the design used none."""
        stored = self.parameters.get("design_file")
        return resolve_for_file(stored, self.path) if stored else None

    @property
    def id(self) -> str:
        """Short identifier for logs and diagnostics: ``<method>:<sha of the plant>[:12]``."""
        return f"{self.method}:{Path(self.path).stem}:{self.system_sha256[:12]}"


def to_plain(obj: Any) -> Any:
    """Recursively turn numpy arrays and scalars into lists and floats for YAML."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    return obj


def _is_numeric_tree(v: Any) -> bool:
    if isinstance(v, bool):
        return False
    if isinstance(v, (int, float)):
        return True
    return isinstance(v, list) and len(v) > 0 and all(_is_numeric_tree(e) for e in v)


def from_plain(obj: Any) -> Any:
    """Inverse of :func:`to_plain`: rectangular numeric lists become float arrays."""
    if isinstance(obj, Mapping):
        return {k: from_plain(v) for k, v in obj.items()}
    if isinstance(obj, list) and obj and _is_numeric_tree(obj):
        try:
            return np.asarray(obj, dtype=float)
        except ValueError:  # ragged: keep as a list of arrays
            return [from_plain(v) for v in obj]
    if isinstance(obj, list):
        return [from_plain(v) for v in obj]
    return obj


class _Dumper(yaml.SafeDumper):
    pass


def _float_repr(dumper: yaml.SafeDumper, value: float) -> yaml.Node:
    # repr keeps every digit (round-trip exact); YAML needs .nan/.inf spelled its way.
    if math.isnan(value):
        text = ".nan"
    elif math.isinf(value):
        text = ".inf" if value > 0 else "-.inf"
    else:
        text = repr(value)
    return dumper.represent_scalar("tag:yaml.org,2002:float", text)


_Dumper.add_representer(float, _float_repr)

#: The top-level key holding the digest; it covers every other key of the file.
DIGEST_KEY = "digest"
_PART_HEX = 16  # 64 bits per key path: enough to name the edit; the full SHA-256 decides


def _canonical(obj: Any) -> bytes:
    """Canonical bytes of a parsed YAML value: sorted keys, floats as ``repr`` (exact)."""
    def norm(v: Any) -> Any:
        if isinstance(v, Mapping):
            return {str(k): norm(e) for k, e in v.items()}
        if isinstance(v, (list, tuple)):
            return [norm(e) for e in v]
        return v
    return json.dumps(norm(obj), sort_keys=True, separators=(",", ":"), allow_nan=True,
                      default=str).encode("utf-8")


def _key_paths(obj: Any, prefix: str, out: dict[str, Any]) -> None:
    """Leaves of a gain-file tree by key path (``results.L.m1``, ``results.rows[2].r``).

    Mappings and lists of mappings are descended; a number, a string or a numeric array is
    one leaf.
    """
    if isinstance(obj, Mapping) and obj:
        for k, v in obj.items():
            _key_paths(v, f"{prefix}.{k}" if prefix else str(k), out)
    elif isinstance(obj, list) and any(isinstance(e, Mapping) for e in obj):
        for i, v in enumerate(obj):
            _key_paths(v, f"{prefix}[{i}]", out)
    else:
        out[prefix] = obj


def gain_digest(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The digest of a gain-file document (as YAML parses it), its own key left out.

    Parameters
    ----------
    doc : mapping
        The parsed gain file.

    Returns
    -------
    dict
        ``{algorithm, sha256, parts}``: ``sha256`` of the canonical form of every key but
        ``digest``; ``parts`` maps each key path (see :func:`_key_paths`) to the first 16 hex
        digits of its own SHA-256.
    """
    body = {k: v for k, v in doc.items() if k != DIGEST_KEY}
    leaves: dict[str, Any] = {}
    _key_paths(body, "", leaves)
    return {
        "algorithm": "sha256 of canonical JSON (sorted keys, repr floats) of every other key",
        "sha256": hashlib.sha256(_canonical(body)).hexdigest(),
        "parts": {p: hashlib.sha256(_canonical(v)).hexdigest()[:_PART_HEX]
                  for p, v in leaves.items()},
    }


def check_digest(doc: Mapping[str, Any], path: str | Path) -> None:
    """Refuse a gain file whose content differs from what its designer wrote.

    Raises
    ------
    GainFileError
        One line naming the key paths that changed (or were added or removed).
    """
    stored = doc.get(DIGEST_KEY)
    sys_info = doc.get("system")
    plant = sys_info.get("name") if isinstance(sys_info, Mapping) else "<plant>"
    redesign = f"redesign with `python -m fd_monitor design {doc.get('method')} {plant}`"
    if not isinstance(stored, Mapping) or not isinstance(stored.get("parts"), Mapping):
        raise GainFileError(f"{path}: {DIGEST_KEY}: missing or malformed (a gain file is "
                            f"written by a designer, which adds it): {redesign}")
    now = gain_digest(doc)
    if stored.get("sha256") == now["sha256"]:
        return
    old = stored["parts"]
    changed = [p for p in now["parts"] if p in old and old[p] != now["parts"][p]]
    added = [p for p in now["parts"] if p not in old]
    removed = [str(p) for p in old if p not in now["parts"]]
    what = ([f"{p} changed" for p in changed] + [f"{p} added" for p in added]
            + [f"{p} removed" for p in removed]) or [f"{DIGEST_KEY}.sha256 changed"]
    more = f" (and {len(what) - 3} more)" if len(what) > 3 else ""
    raise GainFileError(f"{path}: edited after design: {', '.join(what[:3])}{more}; the "
                        f"digest no longer matches, so nothing in the file is trusted: "
                        f"{redesign}")


def write_gain_doc(path: str | Path, doc: Mapping[str, Any]) -> Path:
    """Write a gain-file document with a fresh digest (the one writer of gain files).

    The digest is computed on the document as YAML will parse it back, so the loader sees
    exactly what was digested. Designers call this through :func:`save_gains`.
    """
    body = {k: v for k, v in to_plain(doc).items() if k != DIGEST_KEY}
    text = yaml.dump(body, Dumper=_Dumper, sort_keys=False, width=100)
    body[DIGEST_KEY] = gain_digest(yaml.safe_load(text))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    header = (f"# fd_monitor gain file: method {body.get('method')}, plant "
              f"{(body.get('system') or {}).get('name')}.\n"
              "# Written by a designer; the digest at the end covers every value, so an edit "
              "is refused.\n")
    p.write_text(header + yaml.dump(body, Dumper=_Dumper, sort_keys=False, width=100),
                 encoding="utf-8")
    return p


def save_gains(path: str | Path, method: str, system: System, parameters: Mapping[str, Any],
               results: Mapping[str, Any], certificate: Mapping[str, Any],
               solver: Mapping[str, Any]) -> Path:
    """Write a gain file; return its path.

    Parameters
    ----------
    path : str or pathlib.Path
    method : str
        One of :data:`CERTIFICATE_CHECKS`.
    system : System
        The plant designed for (its name and SHA-256 are recorded).
    parameters, results, certificate, solver : mapping
        Values may be numpy arrays. ``parameters.design_file`` is stored relative to the gain
        file's folder (:func:`fd_monitor.model.paths.path_for_file`); read it back with
        :attr:`GainFile.design_file`.
    """
    if method not in CERTIFICATE_CHECKS:
        raise GainFileError(f"{path}: method: expected one of {sorted(CERTIFICATE_CHECKS)}, "
                            f"got {method!r}")
    parameters = dict(parameters)
    if parameters.get("design_file"):
        # every path a gain file stores is relative to its own folder (POSIX), so a shipped
        # file holds in the checkout, in share/fd_monitor/config and in any copy of the tree
        parameters["design_file"] = path_for_file(parameters["design_file"], path)
    doc = {
        "format_version": FORMAT_VERSION,
        "method": method,
        "system": {"name": system.name, "sha256": system.sha256,
                   **_plant_file(system, path)},
        "created": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "solver": to_plain(solver),
        "parameters": to_plain(parameters),
        "results": to_plain(results),
        "certificate": to_plain(certificate),
    }
    return write_gain_doc(path, doc)


def _plant_file(system: System, gain_path: str | Path) -> dict[str, str]:
    """``{"file": ...}`` when the plant cannot be found by its name (not shipped, or shipped
    under another name), else ``{}``: shipped plants keep their gain files as they were."""
    src = Path(system.source)
    if not src.is_file():
        return {}
    try:
        by_name = find_config_file(system.name, "systems", GainFileError)
    except GainFileError:
        by_name = None
    if by_name is not None and by_name.resolve() == src.resolve():
        return {}
    return {"file": path_for_file(src, gain_path)}


def load_gains(source: str | Path, system: System | None = None, *,
               verify: bool = True) -> GainFile:
    """Read a gain file, check it is for ``system`` and re-verify its certificate.

    Parameters
    ----------
    source : str or pathlib.Path
        A path, or a name in ``config/gains/``.
    system : System, optional
        The plant it must be for; when given, a different plant SHA-256 is refused and the
        certificate is re-checked against it.
    verify : bool
        Re-check the digest (any edit after design is refused, naming the key path) and,
        with ``system``, the certificate.

    Raises
    ------
    GainFileError
        One line naming the file and the problem.

    Examples
    --------
    >>> from fd_monitor.model.system import load_system
    >>> gf = load_gains("three_tank_thresholds", load_system("three_tank"))
    >>> gf.method, gf.system_name
    ('thresholds', 'three_tank')
    """
    path = find_config_file(source, "gains", GainFileError, what="gain file")
    return gains_from_doc(read_yaml(path, GainFileError), path, system, verify=verify)


def gains_from_doc(raw: Any, path: str | Path, system: System | None = None, *,
                   verify: bool = True) -> GainFile:
    """:func:`load_gains` on a gain-file document already parsed from ``path``."""
    if not isinstance(raw, Mapping):
        raise GainFileError(f"{path}: expected a mapping of gain-file keys")
    for key in ("format_version", "method", "system", "parameters", "results", "certificate"):
        if key not in raw:
            raise GainFileError(f"{path}: {key}: missing key (is this an fd_monitor gain file?)")
    if isinstance(raw["format_version"], bool) or raw["format_version"] != FORMAT_VERSION:
        raise GainFileError(f"{path}: format_version: expected {FORMAT_VERSION}, got "
                            f"{raw['format_version']!r}")
    method = raw["method"]
    if not isinstance(method, str) or method not in CERTIFICATE_CHECKS:
        raise GainFileError(f"{path}: method: expected one of {sorted(CERTIFICATE_CHECKS)}, "
                            f"got {method!r}")
    sys_info = raw["system"]
    if not isinstance(sys_info, Mapping) or not {"name", "sha256"} <= set(sys_info):
        raise GainFileError(f"{path}: system: expected {{name, sha256}}")
    for key in ("solver", "parameters", "results", "certificate"):
        if raw.get(key) is not None and not isinstance(raw[key], Mapping):
            raise GainFileError(f"{path}: {key}: expected a mapping, got "
                                f"{type(raw[key]).__name__}")
    if verify:
        check_digest(raw, path)
    stored = sys_info.get("file")
    if stored is not None and (not isinstance(stored, str) or not stored.strip()):
        raise GainFileError(f"{path}: system.file: expected the plant file's path (relative "
                            f"to the gain file's folder), got {stored!r}")
    gf = GainFile(str(path), str(method), str(sys_info["name"]), str(sys_info["sha256"]),
                  str(raw.get("created", "")), dict(raw.get("solver") or {}),
                  dict(raw["parameters"] or {}), from_plain(dict(raw["results"] or {})),
                  from_plain(dict(raw["certificate"] or {})),
                  system_file="" if stored is None else str(resolve_for_file(stored, path)))
    if system is not None:
        if gf.system_sha256 != system.sha256:
            what = ("another plant" if gf.system_name != system.name
                    else "a different version of this plant")
            raise GainFileError(
                f"{path}: designed for {what} ({gf.system_name} {gf.system_sha256[:12]}), "
                f"not {system.name} {system.sha256[:12]}: redesign with "
                f"`python -m fd_monitor design {method} {system.name}`")
        if verify:
            mod_name, fn_name = CERTIFICATE_CHECKS[method].split(":")
            try:
                check = getattr(importlib.import_module(mod_name), fn_name)
            except (ImportError, AttributeError) as exc:
                raise GainFileError(f"{path}: no certificate check for method {method!r} "
                                    f"({exc})") from None
            try:
                check(system, gf)
            except GainFileError as exc:
                raise GainFileError(f"{path}: certificate does not hold: {exc}") from None
            except (KeyError, ValueError, TypeError, IndexError) as exc:
                raise GainFileError(f"{path}: malformed results or certificate: "
                                    f"{type(exc).__name__}: {exc}") from None
            gf = GainFile(gf.path, gf.method, gf.system_name, gf.system_sha256, gf.created,
                          gf.solver, gf.parameters, gf.results, gf.certificate, gf.system_file,
                          "verified")
    return gf
