"""fd_monitor's topics, each declared once: relative name, message type, fields and labels.

Every topic name of the package is written here and nowhere else; the nodes, the recorder,
the offline runner and the commands refer to the declarations. A
``Float64MultiArray`` topic is a sequence of *fields* (``x_hat``, ``residual``, ...), each
one value or one value per state / output / channel; its ``layout.dim[0].label`` is the
fields' labels in order, a function of the plant (:meth:`Topic.labels`). The field names are
those of the core outputs' ``payload()`` (``ObserverOutput``, ``DetectorOutput``,
``AgeiOutput``, ``BiasOutput``), so a message is encoded from payloads by field name
(:meth:`Layout.encode`) and decoded by field name through an index table built once per
subscription (:attr:`Layout.index`), never by position written in a node.

=========================  ======================================================
topic                      fields (labels)
=========================  ======================================================
plant/u                    u (inputs)
plant/y                    y (outputs)
plant/rho                  rho (measured scheduling parameters)
plant/mode                 mode
plant/truth                mode, ``x.<state>``, ``f.<fault>``, ``rho.<parameter>``
fd/state_estimate          mode, x_hat (states), y_tilde (``y~<out>``), restart, bridge
fd/residual                residual (``r:<out>``), w (``w:<out>``)
fd/threshold               threshold (``R:<out>``), nominal (``rbar:<out>``)
fd/alarm                   alarm (outputs, 0/1)
fd/guard_event             trigger, phase, row, mode_uncertain
fd/threshold_override      override (outputs, NaN = none)
fd/bias_estimate           sigma_hat (outputs), isolated (``iso:<out>``), active, k_detect
fd/fault                   fault (``fault:<ch>``), isolated (``iso:<ch>``), estimate
                           (``est:<ch>``), since (``since:<ch>``, -1 = none): the latched
                           verdict (published on change, transient local)
fd/reset                   (std_msgs/Empty) a chain node's ``~/reset`` asks the chain's
                           entry to start a new run
/diagnostics               (diagnostic_msgs/DiagnosticArray)
=========================  ======================================================

A node running a registry runtime (``qb``, ``hinf_sc``, ``hminus_switched``) publishes
``fd/residual``, ``fd/threshold``, ``fd/alarm`` and ``fd/state_estimate`` with the runtime's
channels as labels (:meth:`Topic.channels`, :func:`runtime_estimate`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fd_monitor.core.simulator import measured_layout

__all__ = [
    "ALARM",
    "BIAS_ESTIMATE",
    "CHAIN_DATA",
    "CHAIN_OUTPUTS",
    "RUNTIME_OUTPUTS",
    "DIAGNOSTICS",
    "DIAGNOSTIC_ARRAY",
    "EMPTY",
    "FAULT",
    "FLOAT64_MULTI_ARRAY",
    "Field",
    "GUARD_EVENT",
    "Layout",
    "PLANT_MODE",
    "PLANT_RHO",
    "PLANT_TRUTH",
    "PLANT_U",
    "PLANT_Y",
    "RESET",
    "RESIDUAL",
    "STATE_ESTIMATE",
    "THRESHOLD",
    "THRESHOLD_OVERRIDE",
    "TOPICS",
    "Topic",
    "fault_layout",
    "runtime_estimate",
    "side_topic",
]

#: Message type of every data topic (rosbag2 / ROS 2 type name).
FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
#: Message type of ``/diagnostics``.
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
#: Message type of ``fd/reset``.
EMPTY = "std_msgs/msg/Empty"


@dataclass(frozen=True)
class Field:
    """One field of a topic.

    Attributes
    ----------
    name : str
        The key of the value in a core output's ``payload()``.
    labels : callable, optional
        ``labels(source)`` -> the field's channel names (one per value); None: one value,
        labelled with the field's name.
    """

    name: str
    labels: Callable[[Any], tuple[str, ...]] | None = None

    @property
    def scalar(self) -> bool:
        """One value (labelled by the field's name)."""
        return self.labels is None

    def labels_for(self, source: Any) -> tuple[str, ...]:
        """The field's labels for a plant (a scenario for ``plant/truth``)."""
        return (self.name,) if self.labels is None else tuple(self.labels(source))


@dataclass(frozen=True)
class Layout:
    """A topic's layout for one plant: its labels and the index of each field in ``data``
    (after the stamp). Built once per publisher or subscription.

    Attributes
    ----------
    labels : tuple of str
        (m,) channel names, in order.
    fields : tuple of (str, bool)
        Field name, scalar, in order.
    index : dict
        Field name -> int (a scalar field) or slice (a vector field) into the (m,) values.
    """

    labels: tuple[str, ...]
    fields: tuple[tuple[str, bool], ...]
    index: Mapping[str, int | slice]

    def encode(self, *payloads: Mapping[str, Any], **extra: Any) -> np.ndarray:
        """(m,) values from payloads by field name (``extra``: fields no payload holds).

        Parameters
        ----------
        *payloads : mapping of str to array_like
            Core outputs' ``payload()``; a field is taken from the first that has it.
        **extra
            Fields given directly (``restart``, ``bridge`` of ``fd/state_estimate``).
        """
        parts = []
        srcs = (*payloads, extra)
        for name, _ in self.fields:
            src = next((p for p in srcs if name in p), None)
            if src is None:
                raise ValueError(f"field {name} is in none of the payloads")
            parts.append(np.ravel(np.asarray(src[name], dtype=float)))
        values = np.concatenate(parts) if parts else np.zeros(0)
        if values.size != len(self.labels):
            raise ValueError(f"{values.size} values for {len(self.labels)} labels "
                             f"({','.join(self.labels)})")
        return values

    def sources(self, payloads: Sequence[Mapping[str, Any]]) -> tuple[tuple[int, str, bool],
                                                                         ...]:
        """Which of ``payloads`` holds each field: ``(payload index, field, scalar)`` in
        order, resolved once (the fused node's table, read per sample)."""
        out = []
        for name, scalar in self.fields:
            i = next((i for i, p in enumerate(payloads) if name in p), None)
            if i is None:
                raise ValueError(f"field {name} is in none of the payloads")
            out.append((i, name, scalar))
        return tuple(out)


@dataclass(frozen=True)
class Topic:
    """One topic: relative name (absolute for ``/diagnostics``), message type, fields.

    Attributes
    ----------
    name : str
        Relative name (resolved in the node's namespace), e.g. ``plant/y``.
    msg_type : str
        ``pkg/msg/Name``.
    fields : tuple of Field
    next_sample : bool
        Feedback decided at sample k for k + 1, and stamped k + 1 (so every join of a node
        is on equal stamps).
    """

    name: str
    msg_type: str = FLOAT64_MULTI_ARRAY
    fields: tuple[Field, ...] = ()
    next_sample: bool = False

    @property
    def absolute(self) -> str:
        """The name in the root namespace (``/plant/y``): bags, the default graph."""
        return self.name if self.name.startswith("/") else "/" + self.name

    def labels(self, source: Any) -> tuple[str, ...]:
        """Channel names for a plant (:class:`~fd_monitor.model.system.System`; for
        ``plant/truth`` and ``plant/rho`` the :class:`~fd_monitor.model.scenario.Scenario`)."""
        return tuple(lab for f in self.fields for lab in f.labels_for(source))

    def layout(self, source: Any) -> Layout:
        """The labels and the field index table for a plant (see :meth:`labels`)."""
        index: dict[str, int | slice] = {}
        labels: list[str] = []
        for f in self.fields:
            labs = f.labels_for(source)
            index[f.name] = len(labels) if f.scalar else slice(len(labels),
                                                               len(labels) + len(labs))
            labels.extend(labs)
        return Layout(tuple(labels), tuple((f.name, f.scalar) for f in self.fields), index)

    def with_labels(self, labels: Mapping[str, Sequence[str]]) -> Layout:
        """A layout of some of the topic's fields, in their declared order, with the labels
        given per field (what a registry runtime publishes: its own channels)."""
        unknown = set(labels) - {f.name for f in self.fields}
        if unknown:
            raise ValueError(f"{self.name}: no field {', '.join(sorted(unknown))}")
        index: dict[str, int | slice] = {}
        out: list[str] = []
        fields = []
        for f in self.fields:
            if f.name not in labels:
                continue
            labs = tuple(labels[f.name])
            if f.scalar and len(labs) != 1:
                raise ValueError(f"{self.name}: field {f.name} is one value, got {len(labs)} "
                                 f"labels")
            index[f.name] = len(out) if f.scalar else slice(len(out), len(out) + len(labs))
            out.extend(labs)
            fields.append((f.name, f.scalar))
        return Layout(tuple(out), tuple(fields), index)

    def channels(self, labels: Sequence[str]) -> Layout:
        """The layout a registry runtime publishes: the topic's first field, one value per
        channel (``labels``: the runtime's channels)."""
        return self.with_labels({self.fields[0].name: labels})


def _inputs(s: Any) -> tuple[str, ...]:
    return tuple(s.inputs)


def _outputs(s: Any) -> tuple[str, ...]:
    return tuple(s.outputs)


def _prefixed(prefix: str) -> Callable[[Any], tuple[str, ...]]:
    def labels(s: Any) -> tuple[str, ...]:
        return tuple(f"{prefix}{o}" for o in s.outputs)
    return labels


def _measured_rho(sc: Any) -> tuple[str, ...]:
    return measured_layout(sc).get("rho", ((), None))[0]


PLANT_U = Topic("plant/u", fields=(Field("u", _inputs),))
PLANT_Y = Topic("plant/y", fields=(Field("y", _outputs),))
#: The measured scheduling parameters (labels from the scenario).
PLANT_RHO = Topic("plant/rho", fields=(Field("rho", _measured_rho),))
#: The switching signal of a plant no guard switches.
PLANT_MODE = Topic("plant/mode", fields=(Field("mode"),))
#: True mode, state, faults and scheduling parameters (labels from the scenario).
PLANT_TRUTH = Topic("plant/truth", fields=(
    Field("mode"),
    Field("x", lambda sc: tuple(f"x.{s}" for s in sc.system.states)),
    Field("faults", lambda sc: tuple(f"f.{f.name}" for f in sc.system.faults)),
    Field("rho", lambda sc: tuple(f"rho.{n}" for n in sc.rho_names)),
))
STATE_ESTIMATE = Topic("fd/state_estimate", fields=(
    Field("mode"), Field("x_hat", lambda s: tuple(s.states)),
    Field("y_tilde", _prefixed("y~")), Field("restart"), Field("bridge"),
))
RESIDUAL = Topic("fd/residual", fields=(Field("residual", _prefixed("r:")),
                                        Field("w", _prefixed("w:"))))
THRESHOLD = Topic("fd/threshold", fields=(Field("threshold", _prefixed("R:")),
                                          Field("nominal", _prefixed("rbar:"))))
ALARM = Topic("fd/alarm", fields=(Field("alarm", _outputs),))
GUARD_EVENT = Topic("fd/guard_event", fields=(
    Field("trigger"), Field("phase"), Field("row"), Field("mode_uncertain")),
    next_sample=True)
THRESHOLD_OVERRIDE = Topic("fd/threshold_override", fields=(Field("override", _outputs),),
                           next_sample=True)
BIAS_ESTIMATE = Topic("fd/bias_estimate", fields=(
    Field("sigma_hat", _outputs), Field("isolated", _prefixed("iso:")), Field("active"),
    Field("k_detect")), next_sample=True)
#: The latched fault verdict per channel (:mod:`fd_monitor.core.verdict`), published when it
#: changes (reliable, transient local: a late subscriber gets the verdict in force).
FAULT = Topic("fd/fault", fields=(
    Field("fault", _prefixed("fault:")), Field("isolated", _prefixed("iso:")),
    Field("estimate", _prefixed("est:")), Field("since", _prefixed("since:"))))
#: A new run of the whole chain, asked by any chain node's ``~/reset`` of the chain's entry.
RESET = Topic("fd/reset", EMPTY)
DIAGNOSTICS = Topic("/diagnostics", DIAGNOSTIC_ARRAY)

#: What the sensor-bias chain publishes (the fused monitor: all seven, in this order).
CHAIN_OUTPUTS = (STATE_ESTIMATE, RESIDUAL, THRESHOLD, ALARM, GUARD_EVENT,
                 THRESHOLD_OVERRIDE, BIAS_ESTIMATE)

#: Every topic of fd_monitor.
TOPICS = (PLANT_U, PLANT_Y, PLANT_RHO, PLANT_MODE, PLANT_TRUTH, *CHAIN_OUTPUTS, FAULT, RESET,
          DIAGNOSTICS)
#: The sensor-bias chain's data topics: what ``record`` and the demo record by default
#: (with ``/diagnostics``).
CHAIN_DATA = (PLANT_U, PLANT_Y, PLANT_TRUTH, *CHAIN_OUTPUTS)
#: What the fused monitor publishes for a registry runtime that is not the chain (fields of
#: :meth:`fd_monitor.core.runtime.Runtime.payloads`; layouts: the runtime's channels and
#: :func:`runtime_estimate`).
RUNTIME_OUTPUTS = (RESIDUAL, THRESHOLD, ALARM, STATE_ESTIMATE)

_SIDE = {"rho": PLANT_RHO, "mode": PLANT_MODE}


def runtime_estimate(system: Any, channels: Sequence[str], x_hat: Any) -> Layout:
    """``fd/state_estimate`` of a registry runtime: ``mode``, then x^ flattened, labelled
    ``x.<state>`` for one estimate (n,) or ``<channel>.<state>`` for a bank (n_gen, n)."""
    x = np.asarray(x_hat)
    if x.ndim == 1:
        names: tuple[str, ...] = tuple(f"x.{s}" for s in system.states[:x.size])
    else:
        names = tuple(f"{c}.{s}" for c in channels[:x.shape[0]]
                      for s in system.states[:x.shape[1]])
    return STATE_ESTIMATE.with_labels({"mode": ("mode",), "x_hat": names})


def side_topic(name: str) -> Topic:
    """The topic of a runtime's side signal (``rho``, ``mode``:
    :attr:`fd_monitor.core.runtime.Runtime.side_inputs`)."""
    return _SIDE[name]


def fault_layout(channels: Sequence[str]) -> Layout:
    """``fd/fault`` of a node diagnosing ``channels`` (the plant's outputs for the thresholds
    chain, a registry runtime's channels otherwise): four values per channel."""
    return FAULT.with_labels({f.name: tuple(f"{p}{c}" for c in channels)
                              for f, p in zip(FAULT.fields, ("fault:", "iso:", "est:",
                                                             "since:"))})
