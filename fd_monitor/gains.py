"""Gain files: what a designer writes and what the runtime loads, re-checks and runs.

A gain file is YAML with human-readable matrices (nested lists)::

    format_version: 1
    method: qb                       # qb | thresholds | hinf_sc | hminus_switched
    system: {name: pwa_cascade, sha256: <hex of the plant's canonical form>}
    created: 2026-11-22T10:00:00Z
    solver: {name: CLARABEL, status: optimal, time_s: 0.012}
    parameters: {...}                # the design parameters
    results: {...}                   # gains per mode, P, thresholds, ...
    certificate: {...}               # what the loader re-verifies (LMI margins, eigenvalues)

A gain file for another plant (a different SHA-256) is refused. The certificate is checked
by the method's ``check_certificate(system, gains)`` in ``fd_monitor.core`` (numpy only), so
the runtime trusts nothing it cannot recompute.
"""

from __future__ import annotations

import datetime as _dt
import importlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fd_monitor.errors import GainFileError
from fd_monitor.paths import find_config_file
from fd_monitor.system import System, read_yaml

__all__ = ["GainFile", "CERTIFICATE_CHECKS", "load_gains", "save_gains", "to_plain",
           "from_plain"]

FORMAT_VERSION = 1

#: method -> "module:function" that raises GainFileError when the certificate fails.
CERTIFICATE_CHECKS: dict[str, str] = {
    "qb": "fd_monitor.core.qb:check_certificate",
    "thresholds": "fd_monitor.core.thresholds:check_certificate",
    "hinf_sc": "fd_monitor.core.residual_bank:check_certificate",
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
    certificate_status: str = "unchecked"

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
        Values may be numpy arrays.
    """
    if method not in CERTIFICATE_CHECKS:
        raise GainFileError(f"{path}: method: expected one of {sorted(CERTIFICATE_CHECKS)}, "
                            f"got {method!r}")
    doc = {
        "format_version": FORMAT_VERSION,
        "method": method,
        "system": {"name": system.name, "sha256": system.sha256},
        "created": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "solver": to_plain(solver),
        "parameters": to_plain(parameters),
        "results": to_plain(results),
        "certificate": to_plain(certificate),
    }
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    header = (f"# fd_monitor gain file: method {method}, plant {system.name}.\n"
              "# Written by a designer; edited values void the certificate the loader checks.\n")
    p.write_text(header + yaml.dump(doc, Dumper=_Dumper, sort_keys=False, width=100),
                 encoding="utf-8")
    return p


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
        Re-check the certificate (needs ``system``).

    Raises
    ------
    GainFileError
        One line naming the file and the problem.
    """
    path = find_config_file(source, "gains", GainFileError, what="gain file")
    raw = read_yaml(path, GainFileError)
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
    gf = GainFile(str(path), str(method), str(sys_info["name"]), str(sys_info["sha256"]),
                  str(raw.get("created", "")), dict(raw.get("solver") or {}),
                  dict(raw["parameters"] or {}), from_plain(dict(raw["results"] or {})),
                  from_plain(dict(raw["certificate"] or {})))
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
                          gf.solver, gf.parameters, gf.results, gf.certificate, "verified")
    return gf
