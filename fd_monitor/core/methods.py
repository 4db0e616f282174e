"""The one method registry: gain-file ``method`` -> everything the package does with it.

Each gain-file method is one :class:`Method` record: its runtime class
(:class:`~fd_monitor.core.runtime.Runtime`), its certificate check, its one-line help and the
module of its designer's command line. :data:`METHODS` holds the shipped ones; everything
that depends on the method name looks it up here and nowhere else:

* :func:`load_gains` re-checks a gain file's certificate with the method's check (the model
  layer reads the file and runs the check it is passed: :func:`fd_monitor.model.gains.read_gains`,
  so the ground floor never reaches up into core);
* :func:`runtime_for` builds the method's runtime (nodes, offline runs, reports, campaigns);
* ``python -m fd_monitor design <method>`` lists the methods with their help lines and runs
  the chosen one's designer (:mod:`fd_monitor.commands.design`).

Like rosbags' ``Reader.STORAGE_PLUGINS`` (one typed mapping of classes behind a protocol),
but a record per method, because a method is more than its runtime. A registry is a value
(:class:`MethodRegistry`): :func:`load_gains`, :func:`gains_from_doc` and
:func:`runtime_class` take ``methods=`` (default :data:`METHODS`), and
:meth:`MethodRegistry.runtime_for` is :func:`runtime_for` on any registry, so a test
registers a method of its own in a registry of its own and the shipped one is left as it
is. Adding a method: ``doc/howto/add-a-method.md``.

numpy only (no rclpy, no cvxpy): the designer is named, not imported.

>>> sorted(METHODS)
['hinf_sc', 'hminus_switched', 'qb', 'thresholds']
>>> METHODS["qb"].runtime.__name__, METHODS["qb"].designer
('QBRuntime', 'fd_monitor.commands.design_qb')
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from fd_monitor.core import generalized_observer, hinf_certificate, qb_certificate, thresholds
from fd_monitor.core.runtime import (
    HinfScRuntime,
    HminusSwitchedRuntime,
    QBRuntime,
    Runtime,
    ThresholdsRuntime,
)
from fd_monitor.model.errors import GainFileError
from fd_monitor.model.gains import CertificateCheck, GainFile, gain_file_from_doc, read_gains
from fd_monitor.model.system import System

__all__ = ["METHODS", "RUNTIMES", "Method", "MethodRegistry", "gains_from_doc", "load_gains",
           "runtime_class", "runtime_for"]


@dataclass(frozen=True)
class Method:
    """One gain-file method, as the registry knows it.

    Attributes
    ----------
    name : str
        The gain-file ``method`` (the registry key; equal to ``runtime.method``).
    runtime : type of Runtime
        Its runtime class (:func:`runtime_for` builds one per stream).
    check_certificate : CertificateCheck
        ``check(system, gains)``: recomputes the certificate, raises
        :class:`~fd_monitor.model.errors.GainFileError` when it does not hold
        (:func:`load_gains` runs it).
    help : str
        One line: what the method is and whose (``design --help`` lists it).
    designer : str
        The module of its designer's command line (``add_arguments(parser)``,
        ``run(args) -> int``), e.g. ``fd_monitor.commands.design_qb``; a name, imported
        by ``design`` only when the method is chosen (cvxpy is a layer above core).
    """

    name: str
    runtime: type[Runtime]
    check_certificate: CertificateCheck
    help: str
    designer: str

    def __post_init__(self) -> None:
        if self.runtime.method != self.name:
            raise ValueError(f"method {self.name!r}: its runtime {self.runtime.__name__} "
                             f"runs {self.runtime.method!r}")


class MethodRegistry(Mapping[str, Method]):
    """Gain-file method name -> :class:`Method` (read-only mapping plus :meth:`register`).

    Parameters
    ----------
    methods : iterable of Method
        The methods, in the order ``design --help`` lists them.
    """

    def __init__(self, methods: Iterable[Method] = ()) -> None:
        self._methods: dict[str, Method] = {}
        for m in methods:
            self.register(m)

    def register(self, method: Method) -> Method:
        """Add ``method``; a second method of the same name is refused (ValueError)."""
        if method.name in self._methods:
            raise ValueError(f"method {method.name!r} is registered already")
        self._methods[method.name] = method
        return method

    def __getitem__(self, name: str) -> Method:
        return self._methods[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._methods)

    def __len__(self) -> int:
        return len(self._methods)

    def method(self, name: object) -> Method:
        """The method called ``name``; GainFileError naming the known ones."""
        m = self._methods.get(name) if isinstance(name, str) else None
        if m is None:
            raise GainFileError(f"method {name!r}: no runtime for it; known methods: "
                                f"{', '.join(sorted(self._methods))}")
        return m

    def runtime_for(self, system: System, gains: Any, **options: Any) -> Runtime:
        """The runtime of ``gains`` (its ``method`` looked up here) for ``system``, built
        with ``options``; see :func:`runtime_for`."""
        method = getattr(gains, "method", None)
        cls = self.method(str(method) if method is not None else "<none>").runtime
        known = cls.options()
        bad = sorted(set(options) - set(known))
        if bad:
            raise GainFileError(f"method {cls.method!r}: no option {', '.join(bad)} "
                                f"(options: {', '.join(known) or 'none'})")
        return cls(system, gains, **options)

    @property
    def checks(self) -> Mapping[str, CertificateCheck]:
        """Method -> certificate check (what :func:`load_gains` passes down to the model)."""
        return MappingProxyType({n: m.check_certificate for n, m in self._methods.items()})

    @property
    def runtimes(self) -> Mapping[str, type[Runtime]]:
        """Method -> runtime class."""
        return MappingProxyType({n: m.runtime for n, m in self._methods.items()})


#: The shipped methods (the one table: a new method is one more entry).
METHODS = MethodRegistry([
    Method("qb", QBRuntime, qb_certificate.check_certificate,
           "quadratic-boundedness observer (LTI / PWA), Alessandri, Boem & Parisini",
           "fd_monitor.commands.design_qb"),
    Method("thresholds", ThresholdsRuntime, thresholds.check_certificate,
           "filters, filtered-residual thresholds and AGEI matrix, Heracleous et al.",
           "fd_monitor.commands.design_thresholds"),
    Method("hinf_sc", HinfScRuntime, hinf_certificate.check_certificate,
           "bank of H-infinity residual generators with a sensitivity constraint (thesis)",
           "fd_monitor.commands.design_hinf_sc"),
    Method("hminus_switched", HminusSwitchedRuntime, generalized_observer.check_certificate,
           "switched H-minus generalized observer, Farhat & Koenig",
           "fd_monitor.commands.design_hminus_switched"),
])

#: gain-file ``method`` -> runtime class of the shipped methods (a view of :data:`METHODS`).
RUNTIMES: Mapping[str, type[Runtime]] = METHODS.runtimes


def runtime_class(method: object, methods: MethodRegistry | None = None) -> type[Runtime]:
    """The runtime class of a gain-file method (default registry :data:`METHODS`);
    GainFileError naming the known methods."""
    return (METHODS if methods is None else methods).method(method).runtime


def runtime_for(system: System, gains: Any, **options: Any) -> Runtime:
    """The runtime of a loaded gain file for ``system`` (:data:`METHODS`'
    :meth:`MethodRegistry.runtime_for`).

    Parameters
    ----------
    system : System
    gains : GainFile
        Loaded with :func:`load_gains` (its ``method`` picks the runtime).
    **options
        The runtime's keyword options (``agei`` for thresholds, ``rho`` and ``state_bound``
        for qb, ``discretisation`` for hinf_sc, ``design`` and ``threshold`` for
        hminus_switched).

    Raises
    ------
    GainFileError
        Unknown method (one line naming the known ones), or an option the runtime does not
        take.

    Examples
    --------
    >>> from fd_monitor.model.system import load_system
    >>> plant = load_system("pwa_cascade")
    >>> rt = runtime_for(plant, load_gains("pwa_cascade_qb", plant))
    >>> type(rt).__name__, rt.channels[-1]
    ('QBRuntime', 'r_norm')
    >>> out = rt.step(0, [], [0.0, 0.6])        # k, u (this plant has no inputs), y
    >>> out.alarm.shape == (len(rt.channels),)
    True
    """
    return METHODS.runtime_for(system, gains, **options)


def load_gains(source: str | Path, system: System | None = None, *, verify: bool = True,
               methods: MethodRegistry | None = None) -> GainFile:
    """Read a gain file, check it is for ``system`` and re-verify its certificate with its
    method's check (:func:`fd_monitor.model.gains.read_gains` with the registry's checks).

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
    methods : MethodRegistry, optional
        The methods known (default :data:`METHODS`); a gain file of any other is refused.

    Raises
    ------
    GainFileError
        One line naming the file and the problem.

    Examples
    --------
    >>> from fd_monitor.model.system import load_system
    >>> gf = load_gains("three_tank_thresholds", load_system("three_tank"))
    >>> gf.method, gf.system_name, gf.certificate_status
    ('thresholds', 'three_tank', 'verified')
    """
    return read_gains(source, (METHODS if methods is None else methods).checks, system,
                      verify=verify)


def gains_from_doc(raw: Any, path: str | Path, system: System | None = None, *,
                   verify: bool = True, methods: MethodRegistry | None = None) -> GainFile:
    """:func:`load_gains` on a gain-file document already parsed from ``path``."""
    return gain_file_from_doc(raw, path, (METHODS if methods is None else methods).checks,
                              system, verify=verify)
