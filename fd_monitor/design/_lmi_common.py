"""Helpers shared by the LMI designers ``hinf_sc`` and ``hminus_switched``.

Design files
------------
Data the plant schema cannot (yet) express lives in a sibling *design file*
``config/systems/<plant>.design.yaml`` (or a path given with ``--design-file``)::

    format_version: 1
    plant: thesis_4_7            # must be the plant's name
    hinf_sc: {...}               # see fd_monitor.design.hinf_sc
    hminus_switched: {...}       # see fd_monitor.design.hminus_switched

Every validation error is one line naming the file, the key path and what was expected
(:class:`fd_monitor.model.errors.DesignError`).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cvxpy as cp
import numpy as np

from fd_monitor.model.errors import DesignError
from fd_monitor.model.system import System
from fd_monitor.model.validate import Checker, Got
from fd_monitor.model.yaml_io import check_regular_file, parse_yaml_text

__all__ = ["design_checker", "load_design_section", "solve", "left_pinv", "complement_projector",
           "is_observable", "is_detectable", "region_blocks", "SOLVER"]

SOLVER = "CLARABEL"


def design_checker(origin: str, section: str) -> Checker:
    """The :class:`~fd_monitor.model.validate.Checker` of one section of a design file:
    ``DesignError`` ``<file>: <section>.<key>: expected ..., got ...``."""
    return Checker(origin, DesignError, section)


def design_file_for(system: System) -> Path:
    """The sibling design file ``<plant file stem>.design.yaml`` of a plant file."""
    src = Path(system.source)
    return src.with_name(src.stem + ".design.yaml")


def load_design_section(system: System, section: str, path: str | Path | None = None
                        ) -> tuple[Mapping[str, Any], str, str]:
    """Read ``section`` of the plant's design file.

    Returns
    -------
    data : mapping
        The section (empty mapping when the file or the section is missing and ``path`` was
        not given explicitly).
    origin : str
        The file name (for messages and the gain file).
    sha256 : str
        SHA-256 of the file's bytes ("" when there is no file).
    """
    p = Path(path) if path is not None else design_file_for(system)
    if not p.is_file():
        if path is not None:
            check_regular_file(p, DesignError, "design file")
        return {}, str(p), ""
    check_regular_file(p, DesignError, "design file")
    raw = p.read_bytes()
    data = parse_yaml_text(raw, str(p), DesignError)
    if not isinstance(data, Mapping):
        design_checker(str(p), "(top level)").fail("", "a mapping of design-file keys",
                                                    type(data).__name__)
    ck = Checker(str(p), DesignError, clip=None)
    for k in data:
        if k not in ("format_version", "plant", "description", "hinf_sc", "hminus_switched"):
            ck.fail(k, "one of format_version, plant, description, hinf_sc, hminus_switched "
                    "(unknown key)", show=False)
    if isinstance(data.get("format_version"), bool) or data.get("format_version", 1) != 1:
        ck.fail("format_version", "1", data.get("format_version"))
    if data.get("plant") != system.name:
        ck.fail("plant", f"{system.name!r} (the plant being designed for)", data.get("plant"))
    sec = data.get(section)
    if sec is None:
        if path is not None:
            raise DesignError(f"{p}: {section}: missing section")
        return {}, str(p), hashlib.sha256(raw).hexdigest()
    if not isinstance(sec, Mapping):
        ck.fail(section, "a mapping", Got(type(sec).__name__))
    return sec, str(p), hashlib.sha256(raw).hexdigest()


def solve(prob: cp.Problem, what: str, *, raise_on_failure: bool = True
          ) -> tuple[str, float]:
    """Solve with Clarabel; anything but ``optimal`` is a failure.

    Returns
    -------
    status : str
    seconds : float
        Wall time of the solve.
    """
    t0 = time.perf_counter()
    try:
        prob.solve(solver=cp.CLARABEL)
        status = str(prob.status)
    except cp.error.SolverError as exc:
        status = f"solver_error ({exc})"
    dt = time.perf_counter() - t0
    if status != cp.OPTIMAL and raise_on_failure:
        hint = " (infeasible LMI)" if status.startswith("infeasible") else ""
        raise DesignError(f"{what}: solver status {status!r}{hint}; only 'optimal' is "
                          f"accepted")
    return status, dt


def left_pinv(S: np.ndarray) -> np.ndarray:
    """Left pseudo-inverse ``(S'S)^-1 S'`` of a full-column-rank S (thesis eq. 4.41)."""
    return np.linalg.solve(S.T @ S, S.T)


def complement_projector(S: np.ndarray) -> np.ndarray:
    """``I - S S^+``: the orthogonal projection onto the complement of range(S) (4.55)."""
    p = S.shape[0]
    if S.size == 0:
        return np.eye(p)
    return np.eye(p) - S @ np.linalg.pinv(S)


def _pbh_ok(A: np.ndarray, C: np.ndarray, only_unstable: bool, tol: float = 1e-9) -> bool:
    n = A.shape[0]
    scale = max(1.0, float(np.linalg.norm(A)), float(np.linalg.norm(C)))
    for z in np.linalg.eigvals(A):
        if only_unstable and z.real < -1e-12:
            continue
        M = np.vstack([z * np.eye(n) - A, C.astype(complex)])
        if np.linalg.svd(M, compute_uv=False)[-1] <= tol * scale:
            return False
    return True


def is_observable(A: np.ndarray, C: np.ndarray) -> bool:
    """PBH test: ``rank [z I - A; C] = n`` at every eigenvalue z of A."""
    return _pbh_ok(A, C, only_unstable=False)


def is_detectable(A: np.ndarray, C: np.ndarray) -> bool:
    """PBH test at the eigenvalues with ``Re z >= 0`` (continuous time)."""
    return _pbh_ok(A, C, only_unstable=True)


def region_blocks(ctx: Checker, key: str, spec: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """LMI-region characteristic matrices ``(L, M)`` (thesis 2.26-2.27) from a design file.

    Kinds: ``{kind: halfplane, alpha}`` (Re z < -alpha), ``{kind: disk, center, radius}``
    (|z - center| < radius; the thesis' disk centred at (-q, 0) has center = -q),
    ``{kind: sector, angle, apex}`` (|Im z| tan(angle)... the cone of half-angle ``angle``
    (rad) around the negative real axis with apex ``apex``).
    """
    if spec is None:
        return []
    if not isinstance(spec, list):
        ctx.fail(key, "a list of regions {kind: halfplane|disk|sector, ...}", spec)
    out = []
    for i, r in enumerate(spec):
        k = f"{key}[{i}]"
        r = ctx.mapping(k, r)
        kind = r.get("kind")
        if kind == "halfplane":
            ctx.mapping(k, r, {"kind", "alpha"})
            a = ctx.number(f"{k}.alpha", r.get("alpha", 0.0))
            out.append((np.array([[2.0 * a]]), np.array([[1.0]])))
        elif kind == "disk":
            ctx.mapping(k, r, {"kind", "center", "radius"})
            c = ctx.number(f"{k}.center", r.get("center", 0.0))
            rad = ctx.number(f"{k}.radius", r.get("radius"), positive=True)
            out.append((np.array([[-rad, -c], [-c, -rad]]), np.array([[0.0, 1.0], [0.0, 0.0]])))
        elif kind == "sector":
            ctx.mapping(k, r, {"kind", "angle", "apex"})
            th = ctx.number(f"{k}.angle", r.get("angle"), positive=True)
            if th >= math.pi / 2:
                ctx.fail(f"{k}.angle", "a half-angle in (0, pi/2) rad", th)
            b = ctx.number(f"{k}.apex", r.get("apex", 0.0))
            s, c = math.sin(th), math.cos(th)
            out.append((np.array([[-2 * b * s, 0.0], [0.0, -2 * b * s]]),
                        np.array([[s, c], [-c, s]])))
        else:
            ctx.fail(f"{k}.kind", "halfplane, disk or sector", kind)
    return out


