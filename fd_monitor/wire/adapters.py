"""Message adapters: a robot's own topics as the monitor's input and output channels.

A robot's drivers publish ``sensor_msgs/JointState``, ``nav_msgs/Odometry``,
``geometry_msgs/Twist``, ``std_msgs/Float64`` or plain ``std_msgs/Float64MultiArray``, not
fd_monitor's self-describing ``plant/u`` / ``plant/y``. An adapter file maps each plant
input and output channel onto a topic, a type and a field::

    format_version: 1
    inputs:                     # one entry per plant input, any order
      - {channel: effort, topic: /effort_controller/commands,
         type: std_msgs/msg/Float64MultiArray, index: 0}
    outputs:                    # one entry per plant output; the first one's topic is the
      - {channel: velocity, topic: /joint_states,       # sample clock
         type: sensor_msgs/msg/JointState, joint: motor, field: velocity}

Per type (``type: sensor_msgs/JointState`` or ``sensor_msgs/msg/JointState``):

- ``sensor_msgs/msg/JointState``: ``joint`` (a name of ``name[]``) and ``field``
  (``position``, ``velocity`` or ``effort``);
- ``nav_msgs/msg/Odometry``: ``field`` a leaf of the message (``pose.pose.position.x``,
  ``twist.twist.angular.z``, ...; short forms ``position.x``, ``orientation.w``,
  ``linear.x``, ``angular.z``) or ``yaw`` (rad, from the orientation quaternion);
- ``geometry_msgs/msg/Twist``: ``field`` ``linear.x`` ... ``angular.z``;
  ``geometry_msgs/msg/TwistStamped``: the same (``twist.`` may be omitted);
- ``std_msgs/msg/Float64``: nothing else (``data``);
- ``std_msgs/msg/Float64MultiArray``: ``label`` (a name of ``layout.dim[0].label``) or
  ``index`` (position in the values, after ``layout.data_offset``).

Timing (the one time base, :mod:`fd_monitor.wire.timebase`). A message's time is its
``header.stamp`` where the type has a header (JointState, Odometry, TwistStamped; stamp 0 is
a stamp), else its receive time (bag time offline). Every channel is sampled onto the plant's
grid ``k Ts``, phased on the *clock topic* (the first output's): the message of sample k is
the one within half a sample of ``t_k`` (jitter absorbed), a faster topic is decimated (its
last value, or the mean with ``decimate: mean``), a slower one is held up to the channel's
``max_hold`` (s; default :data:`DEFAULT_MAX_HOLD_INPUT` for inputs -- an actuator holds its
command -- and 0 for outputs -- a held measurement is not a measurement), past it the sample
is a gap (``stale``). Adapter-wide defaults: top-level ``max_hold: {inputs: S, outputs: S}``
and ``wait`` (s the stream moves on before a slower topic is held).

Pure: decoding reads attributes of already deserialised messages, so the same code decodes
the dataclasses ``rosbags`` reads from a bag and rclpy's messages; nothing here imports rclpy.
:class:`AdapterJoin` is the one join (time is an argument): :func:`read_adapted` runs it over
a bag (``analyze --adapter``, ``identify --adapter``), the nodes run it live
(:mod:`fd_monitor.nodes.adapter_input`), :func:`encode` builds the robot's messages from
(u, y) (``simulate --adapter``, ``plant_sim -p adapter:=``).

Why one module of ~920 lines: adapter schema, decoding, the join and offline I/O; issue 22
item 3 splits it (and puts the join on the one hold rule), deferred while the wire layer was
being changed by other work.
"""

from __future__ import annotations

import contextlib
import heapq
import math
from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.model.errors import BagError, FdMonitorError, MessageError
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.system import read_yaml
from fd_monitor.wire.bag_reader import _typestore, messages_from_raw
from fd_monitor.wire.bag_scanner import read_raw
from fd_monitor.wire.series import Series
from fd_monitor.wire.timebase import WAIT, Gap, GridSample, GridSampler, NewRun, snap_sample_time

__all__ = ["ADAPTER_TYPES", "Adapter", "AdapterError", "AdapterJoin", "AdaptedMessageError",
           "AdaptedEvent", "AdaptedRun", "AdaptedSample", "AdaptedStreams", "Channel",
           "HOLD_WAIT", "Reading",
           "adapted_events", "decode_message", "encode", "feed", "stamp_sample_time",
           "load_adapter", "parse_adapter", "read_adapted", "rosbags_make", "write_adapted"]


class AdapterError(FdMonitorError, ValueError):
    """An adapter file is missing, unreadable or invalid."""


class AdaptedMessageError(MessageError):
    """A robot message the adapter cannot read; ``kind`` is ``non_finite`` or
    ``malformed`` (the offline report's kinds)."""

    def __init__(self, message: str, kind: str = "malformed") -> None:
        super().__init__(message)
        self.kind = kind


_VEC = ("x", "y", "z")
_ODOM_LEAVES = (*(f"pose.pose.position.{a}" for a in _VEC),
                *(f"pose.pose.orientation.{a}" for a in (*_VEC, "w")),
                *(f"twist.twist.linear.{a}" for a in _VEC),
                *(f"twist.twist.angular.{a}" for a in _VEC), "yaw")
_TWIST_LEAVES = (*(f"linear.{a}" for a in _VEC), *(f"angular.{a}" for a in _VEC))

#: Supported message types -> (has a header, valid ``field`` values or None).
ADAPTER_TYPES: dict[str, tuple[bool, tuple[str, ...] | None]] = {
    "sensor_msgs/msg/JointState": (True, ("position", "velocity", "effort")),
    "nav_msgs/msg/Odometry": (True, _ODOM_LEAVES),
    "geometry_msgs/msg/Twist": (False, _TWIST_LEAVES),
    "geometry_msgs/msg/TwistStamped": (True, tuple(f"twist.{f}" for f in _TWIST_LEAVES)),
    "std_msgs/msg/Float64": (False, ("data",)),
    "std_msgs/msg/Float64MultiArray": (False, None),
}

#: s an input (a command) is held at most by default: an actuator holds its last command.
DEFAULT_MAX_HOLD_INPUT = 0.5
#: s an output (a measurement) is held at most by default: none (a lost one is a gap).
DEFAULT_MAX_HOLD_OUTPUT = 0.0
#: s a live sample waits in silence before the topics not heard are held (offline: the same
#: rule on the bag's log times).
HOLD_WAIT = 0.5

#: Short forms of ``field`` (Odometry, TwistStamped) -> the full path.
_SHORT = {
    "nav_msgs/msg/Odometry": {**{f"position.{a}": f"pose.pose.position.{a}" for a in _VEC},
                              **{f"orientation.{a}": f"pose.pose.orientation.{a}"
                                 for a in (*_VEC, "w")},
                              **{f"linear.{a}": f"twist.twist.linear.{a}" for a in _VEC},
                              **{f"angular.{a}": f"twist.twist.angular.{a}" for a in _VEC}},
    "geometry_msgs/msg/TwistStamped": {f: f"twist.{f}" for f in _TWIST_LEAVES},
}


@dataclass(frozen=True)
class Channel:
    """One mapped channel.

    Attributes
    ----------
    name : str
        The plant's input or output name.
    topic : str
    msgtype : str
        ``pkg/msg/Type``.
    field : str
        Leaf path (``velocity``, ``twist.twist.linear.x``, ``yaw``, ``data``); ``""`` for a
        Float64MultiArray.
    joint : str
        JointState: the joint name.
    label : str
        Float64MultiArray: the channel label (``""``: by ``index``).
    index : int
        Float64MultiArray: position in the values (-1: by ``label``).
    max_hold : float or None
        s the value is held at most (None: the adapter's default for its role).
    decimate : str
        ``last`` or ``mean``: the value of a sample with several messages.
    """

    name: str
    topic: str
    msgtype: str
    field: str = ""
    joint: str = ""
    label: str = ""
    index: int = -1
    max_hold: float | None = None
    decimate: str = "last"

    @property
    def where(self) -> str:
        """``topic[joint].field`` for messages."""
        what = (f"[{self.joint}].{self.field}" if self.joint else
                f"[{self.label!r}]" if self.label else
                f"[{self.index}]" if self.index >= 0 else f".{self.field}")
        return f"{self.topic}{what}"


@dataclass(frozen=True)
class Adapter:
    """A loaded adapter file: the plant's channels on the robot's topics.

    Attributes
    ----------
    source : str
    inputs, outputs : tuple of Channel
        In the file's order (:meth:`for_system` reorders them as the plant's).
    clock_topic : str
        The first output's topic: the grid's phase.
    hold_inputs, hold_outputs : float
        s, the default ``max_hold`` of inputs and outputs.
    wait : float
        s the stream moves on before a slower topic is held.
    """

    source: str
    inputs: tuple[Channel, ...]
    outputs: tuple[Channel, ...]
    clock_topic: str = ""
    hold_inputs: float = DEFAULT_MAX_HOLD_INPUT
    hold_outputs: float = DEFAULT_MAX_HOLD_OUTPUT
    wait: float = WAIT

    def __post_init__(self) -> None:
        if not self.clock_topic:
            # the sample clock: the file's first output's topic
            object.__setattr__(self, "clock_topic", self.outputs[0].topic)

    @property
    def topics(self) -> dict[str, str]:
        """topic -> message type, every mapped topic: the inputs' first, the sample clock
        last. Subscriptions are made in this order, so an executor that finds a command and
        the measurement after it both waiting takes the command first, as they were sent."""
        out: dict[str, str] = {}
        for c in (*self.inputs, *self.outputs):
            if c.topic != self.clock_topic:
                out.setdefault(c.topic, c.msgtype)
        out[self.clock_topic] = next(c.msgtype for c in self.outputs
                                     if c.topic == self.clock_topic)
        return out

    def header_topic(self, topic: str) -> bool:
        """Whether ``topic``'s type carries a header stamp."""
        return ADAPTER_TYPES[self.topics[topic]][0]

    def for_system(self, system: Any) -> Adapter:
        """This adapter with its channels in the plant's order; AdapterError naming the
        channel when it does not map exactly the plant's inputs and outputs."""
        def order(chs: Sequence[Channel], names: Sequence[str], what: str) -> tuple[Channel, ...]:
            got = {c.name: c for c in chs}
            missing = [n for n in names if n not in got]
            extra = [n for n in got if n not in names]
            if missing or extra:
                raise AdapterError(
                    f"{self.source}: {what}: "
                    + (f"no mapping for {', '.join(missing)}" if missing else "")
                    + ("; " if missing and extra else "")
                    + (f"{', '.join(extra)} not a plant {what[:-1]}" if extra else "")
                    + f" (plant {system.name} {what}: {', '.join(names) or 'none'})")
            return tuple(got[n] for n in names)

        return replace(self, inputs=order(self.inputs, system.inputs, "inputs"),
                       outputs=order(self.outputs, system.outputs, "outputs"))

    def max_hold(self, c: Channel) -> float:
        """s channel ``c`` is held at most."""
        if c.max_hold is not None:
            return c.max_hold
        return self.hold_inputs if c in self.inputs else self.hold_outputs


def load_adapter(source: str | Path) -> Adapter:
    """Read an adapter file: a path, or a shipped name in ``config/adapters/``.

    Raises
    ------
    AdapterError
        One line naming the file, the key path and what was expected.
    """

    path = find_config_file(source, "adapters", AdapterError, "adapter")
    return parse_adapter(read_yaml(path, AdapterError), str(path))


def _type_name(text: Any, where: str) -> str:
    if not isinstance(text, str):
        raise AdapterError(f"{where}.type: expected a message type such as "
                           f"sensor_msgs/msg/JointState, got {text!r}")
    parts = text.strip().split("/")
    full = f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else text.strip()
    if full not in ADAPTER_TYPES:
        raise AdapterError(f"{where}.type: {text!r}: expected one of "
                           f"{', '.join(sorted(ADAPTER_TYPES))}")
    return full


def parse_adapter(doc: Any, source: str = "<adapter>") -> Adapter:
    """Validate an adapter document (see the module docstring)."""
    if not isinstance(doc, Mapping):
        raise AdapterError(f"{source}: expected a mapping with inputs: and outputs:")
    unknown = sorted(set(doc) - {"format_version", "description", "inputs", "outputs",
                                 "max_hold", "wait"})
    if unknown:
        raise AdapterError(f"{source}: {unknown[0]}: unknown key (expected format_version, "
                           f"description, inputs, outputs, max_hold, wait)")
    holds = doc.get("max_hold", {})
    if not isinstance(holds, Mapping) or set(holds) - {"inputs", "outputs"}:
        raise AdapterError(f"{source}: max_hold: expected a mapping {{inputs: s, outputs: s}}, "
                           f"got {holds!r}")
    hold_in = _seconds(holds.get("inputs", DEFAULT_MAX_HOLD_INPUT), f"{source}: max_hold.inputs")
    hold_out = _seconds(holds.get("outputs", DEFAULT_MAX_HOLD_OUTPUT),
                        f"{source}: max_hold.outputs")
    wait = _seconds(doc.get("wait", WAIT), f"{source}: wait")
    if doc.get("format_version", 1) != 1:
        raise AdapterError(f"{source}: format_version: expected 1, got "
                           f"{doc.get('format_version')!r}")
    chans: dict[str, tuple[Channel, ...]] = {}
    for role in ("inputs", "outputs"):
        items = doc.get(role, [] if role == "inputs" else None)
        if not isinstance(items, list) or (role == "outputs" and not items):
            raise AdapterError(f"{source}: {role}: expected a list of channel mappings"
                               + (" (at least one: the outputs' topic is the sample clock)"
                                  if role == "outputs" else ""))
        chans[role] = tuple(_channel(it, f"{source}: {role}[{i}]")
                            for i, it in enumerate(items))
    for role in ("inputs", "outputs"):
        seen: set[str] = set()
        for c in chans[role]:
            if c.name in seen:
                raise AdapterError(f"{source}: {role}: channel {c.name!r} mapped twice")
            seen.add(c.name)
    types: dict[str, str] = {}
    for c in (*chans["outputs"], *chans["inputs"]):
        if types.setdefault(c.topic, c.msgtype) != c.msgtype:
            raise AdapterError(f"{source}: topic {c.topic}: mapped as {types[c.topic]} and "
                               f"as {c.msgtype} (one type per topic)")
    return Adapter(source, chans["inputs"], chans["outputs"], "", hold_in, hold_out, wait)


def _seconds(v: Any, where: str) -> float:
    """A duration in s (>= 0, finite); AdapterError naming ``where``."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise AdapterError(f"{where}: expected a duration in s (a number >= 0), got {v!r}")
    return float(v)


def _channel(item: Any, where: str) -> Channel:
    if not isinstance(item, Mapping):
        raise AdapterError(f"{where}: expected a mapping {{channel, topic, type, ...}}, got "
                           f"{item!r}")
    allowed = {"channel", "topic", "type", "field", "joint", "label", "index", "max_hold",
               "decimate"}
    extra = sorted(set(item) - allowed)
    if extra:
        raise AdapterError(f"{where}.{extra[0]}: unknown key (expected "
                           f"{', '.join(sorted(allowed))})")
    for key in ("channel", "topic"):
        v = item.get(key)
        if not isinstance(v, str) or not v.strip() or "," in v:
            raise AdapterError(f"{where}.{key}: expected a name, got {v!r}")
    topic = str(item["topic"]).strip()
    name = str(item["channel"]).strip()
    timing: dict[str, Any] = {}
    if "max_hold" in item:
        timing["max_hold"] = _seconds(item["max_hold"], f"{where}.max_hold")
    if "decimate" in item:
        if item["decimate"] not in ("last", "mean"):
            raise AdapterError(f"{where}.decimate: expected last or mean, got "
                               f"{item['decimate']!r}")
        timing["decimate"] = item["decimate"]
    ty = _type_name(item.get("type"), where)
    leaves = ADAPTER_TYPES[ty][1]
    fld = item.get("field")
    joint, label, index = "", "", -1
    if ty == "std_msgs/msg/Float64MultiArray":
        if fld is not None or "joint" in item:
            raise AdapterError(f"{where}: a Float64MultiArray channel takes label or index, "
                               f"not field or joint")
        if ("label" in item) == ("index" in item):
            raise AdapterError(f"{where}: expected exactly one of label (a name in "
                               f"layout.dim[0].label) or index (0, 1, ...)")
        if "label" in item:
            label = item["label"]
            if not isinstance(label, str) or not label.strip():
                raise AdapterError(f"{where}.label: expected a channel label, got {label!r}")
            label = label.strip()
        else:
            index = item["index"]
            if isinstance(index, bool) or not isinstance(index, int) or index < 0:
                raise AdapterError(f"{where}.index: expected an integer >= 0, got {index!r}")
        return Channel(name, topic, ty, "", "", label, int(index), **timing)
    if "label" in item or "index" in item:
        raise AdapterError(f"{where}: label and index are for Float64MultiArray channels")
    if ty == "std_msgs/msg/Float64":
        fld = "data" if fld is None else fld
    if ty == "sensor_msgs/msg/JointState":
        j = item.get("joint")
        if not isinstance(j, str) or not j.strip():
            raise AdapterError(f"{where}.joint: expected the joint's name (in name[]), got "
                               f"{j!r}")
        joint = j.strip()
    elif "joint" in item:
        raise AdapterError(f"{where}.joint: only JointState channels name a joint")
    if not isinstance(fld, str):
        raise AdapterError(f"{where}.field: expected one of {', '.join(leaves or ())}, got "
                           f"{fld!r}")
    fld = _SHORT.get(ty, {}).get(fld.strip(), fld.strip())
    assert leaves is not None
    if fld not in leaves:
        raise AdapterError(f"{where}.field: {item.get('field')!r} is not a field of {ty} "
                           f"(expected one of {', '.join(leaves)})")
    return Channel(name, topic, ty, fld, joint, **timing)


# -- decoding ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reading:
    """The mapped values of one message.

    Attributes
    ----------
    topic : str
    stamp_ns : int
        Header stamp (ns), or the receive time for a type without one / a zero stamp.
    receive_ns : int
        Receive time (bag time offline), ns.
    header : bool
        ``stamp_ns`` is a header stamp.
    values : dict
        channel name -> float.
    """

    topic: str
    stamp_ns: int
    receive_ns: int
    header: bool
    values: dict[str, float]


def _leaf(msg: Any, path: str) -> Any:
    obj = msg
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def _yaw(msg: Any) -> float:
    q = msg.pose.pose.orientation
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _value(c: Channel, msg: Any, where: str) -> float:
    ty = c.msgtype
    if ty == "sensor_msgs/msg/JointState":
        names = [str(n) for n in msg.name]
        if c.joint not in names:
            raise AdaptedMessageError(f"{where}: no joint {c.joint!r} (joints: "
                               f"{', '.join(names) or 'none'})")
        arr = getattr(msg, c.field)
        i = names.index(c.joint)
        if len(arr) <= i:
            raise AdaptedMessageError(f"{where}: no {c.field} for joint {c.joint!r} ({c.field}[] "
                               f"has {len(arr)} values for {len(names)} joints)")
        return float(arr[i])
    if ty == "std_msgs/msg/Float64MultiArray":
        data = msg.data
        off = int(msg.layout.data_offset)
        n = len(data) - off
        if c.label:
            dims = list(msg.layout.dim)
            labels = [s.strip() for s in str(dims[0].label).split(",")] if dims else []
            if c.label not in labels:
                raise AdaptedMessageError(f"{where}: no label {c.label!r} (labels: "
                                   f"{', '.join(x for x in labels if x) or 'none'})")
            i = labels.index(c.label)
        else:
            i = c.index
        if not 0 <= i < n:
            raise AdaptedMessageError(f"{where}: index {i} out of range ({max(n, 0)} values)")
        return float(data[off + i])
    if c.field == "yaw":
        return _yaw(msg)
    return float(_leaf(msg, c.field))


def _stamp_ns(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def decode_message(adapter: Adapter, topic: str, msg: Any, receive_ns: int) -> Reading:
    """The values of every channel mapped on ``topic`` in ``msg``.

    Raises
    ------
    AdaptedMessageError
        One line naming topic, channel and what is wrong (unknown joint or label, missing
        field, non-finite value, a message of another type).
    """
    header = adapter.header_topic(topic)
    at = f"{topic} at {receive_ns * 1e-9:.3f} s"
    stamp = receive_ns
    try:
        if header:
            stamp = _stamp_ns(msg)      # stamp 0 is a stamp (a clock starting at 0)
            at = f"{topic} stamp {stamp * 1e-9:.3f} s"
        values: dict[str, float] = {}
        for c in (*adapter.outputs, *adapter.inputs):
            if c.topic != topic:
                continue
            v = _value(c, msg, f"{at} ({c.name})")
            if not math.isfinite(v):
                raise AdaptedMessageError(f"{at} ({c.name} = {c.where}): value is {v!r}: "
                                          f"expected a finite number", "non_finite")
            values[c.name] = v
    except (AttributeError, TypeError, ValueError, IndexError) as exc:
        if isinstance(exc, MessageError):
            raise
        raise AdaptedMessageError(f"{at}: not a {adapter.topics[topic]} with the mapped fields "
                           f"({type(exc).__name__}: {exc})") from None
    return Reading(topic, stamp, receive_ns, header, values)


# -- the join --------------------------------------------------------------------------------


@dataclass(frozen=True)
class AdaptedSample:
    """One sample of the monitor: index, time and the plant's u and y.

    Attributes
    ----------
    k : int
    t_ns : int
        The grid instant on the clock topic's time (header stamp or receive time), ns.
    u, y : numpy.ndarray
        (nu,), (ny,) in the plant's (the adapter's) channel order.
    held : tuple of str
        Channels held from an earlier sample (within their max_hold).
    """

    k: int
    t_ns: int
    u: np.ndarray
    y: np.ndarray
    held: tuple[str, ...] = ()


#: What :meth:`AdapterJoin.events` gives: a sample, a gap (sample k not usable) or a new run.
AdaptedEvent = AdaptedSample | Gap | NewRun


class AdapterJoin:
    """The robot's messages -> samples on the plant's grid (:mod:`fd_monitor.wire.timebase`).

    Pure; time is an argument. :meth:`put` each message (arrival order live, bag order
    offline, with ``now`` the arrival or log time in s); :meth:`events` gives what was decided.
    Live and offline run exactly this, so a bag gives the same samples in both. A channel
    without a message in a sample is held by the one hold rule
    (:class:`~fd_monitor.wire.hold.ZeroOrderHold`, on the grid's slots, up to its
    ``max_hold``), the rule the nodes pair plain inputs by.

    Parameters
    ----------
    adapter : Adapter
        Channels in the order u and y are built in (:meth:`Adapter.for_system`).
    sample_time : float
        s, the plant's Ts.
    hold_wait : float
        s of silence after which the topics not heard for the pending samples are held
        (:data:`HOLD_WAIT`).
    """

    def __init__(self, adapter: Adapter, sample_time: float,
                 hold_wait: float = HOLD_WAIT) -> None:
        if not (isinstance(sample_time, (int, float)) and sample_time > 0
                and math.isfinite(sample_time)):
            raise AdapterError(f"{adapter.source}: sample time {sample_time!r}: expected > 0")
        self.adapter = adapter
        self.hold_wait = float(hold_wait)
        self.clock = adapter.clock_topic
        chans = (*adapter.outputs, *adapter.inputs)
        topics = {t: tuple(c.name for c in chans if c.topic == t) for t in adapter.topics}
        self.sampler = GridSampler(
            topics, self.clock, float(sample_time),
            {t: adapter.header_topic(t) for t in topics},
            {c.name: adapter.max_hold(c) for c in chans},
            [c.name for c in chans if c.decimate == "mean"], adapter.wait)
        #: ``(kind, line)`` reports since the last :meth:`take_errors`: messages that do not
        #: decode (``non_finite``, ``malformed``) and the sampler's notes.
        self.errors: list[tuple[str, str]] = []
        #: Messages that did not decode: kind -> count.
        self.bad: dict[str, int] = {}
        self._last: float | None = None
        self._notes = 0

    def reset(self) -> None:
        """Forget the run (``~/reset``): a new grid from the next messages."""
        self.sampler.reset()
        self._last = None

    def put(self, topic: str, msg: Any, receive_ns: int, now: float | None = None) -> None:
        """Decode one message and place it on the grid; a bad one is added to
        :attr:`errors` (one line) and dropped. ``now`` (s): arrival time (bag log time
        offline; None: no time, no silence rule); a silence of ``hold_wait`` before it
        decides the pending samples first."""
        if now is not None:
            self.advance(now)
            self._last = now
        try:
            r = decode_message(self.adapter, topic, msg, receive_ns)
        except AdaptedMessageError as exc:
            self.bad[exc.kind] = self.bad.get(exc.kind, 0) + 1
            self.errors.append((exc.kind, str(exc)))
            return
        self.sampler.put(r.topic, r.stamp_ns, r.receive_ns, r.values)

    def advance(self, now: float | None) -> None:
        """Time ``now`` (s) passed: ``hold_wait`` s after the last message, decide what is
        pending (None: the end of the data, decide everything)."""
        if now is None or (self._last is not None and now - self._last >= self.hold_wait):
            self.sampler.flush()

    def events(self, final: bool = False) -> list[AdaptedEvent]:
        """Samples, gaps and new runs decided so far (``final``: the end of the data)."""
        a = self.adapter
        out: list[AdaptedEvent] = []
        for e in self.sampler.ready(final):
            if isinstance(e, GridSample):
                v = e.values
                out.append(AdaptedSample(e.k, e.t_ns, np.array([v[c.name] for c in a.inputs]),
                                         np.array([v[c.name] for c in a.outputs]), e.held))
            else:
                out.append(e)
        notes = self.sampler.notes
        self.errors += notes[self._notes:]
        self._notes = len(notes)
        return out

    def ready(self, now: float | None = None) -> list[AdaptedSample]:
        """The samples only (gaps and new runs are in :meth:`events`); ``now`` None: the end."""
        self.advance(now)
        return [e for e in self.events(now is None) if isinstance(e, AdaptedSample)]

    def take_errors(self) -> list[tuple[str, str]]:
        """The ``(kind, line)`` errors since the last call."""
        out, self.errors = self.errors, []
        return out

    def counts(self) -> dict[str, Any]:
        """Everything counted (:meth:`GridSampler.summary`) plus the bad messages."""
        return {**self.sampler.summary(), "bad_messages": dict(self.bad)}


def feed(stream: Any, event: AdaptedEvent, now: float, with_u: bool = True) -> bool:
    """One event of :meth:`AdapterJoin.events` into the nodes' input policy
    (:class:`~fd_monitor.wire.stream.InputStream`, inputs ``u`` and ``y``): a sample is joined,
    a gap refused (the join declares its hole at once), a new run restarts the join. The
    node's callback and the offline reader both call this. True when a sample was joined."""
    if isinstance(event, AdaptedSample):
        ok = stream.put("u", event.k, event.u, now) if with_u else True
        return stream.put("y", event.k, event.y, now) and ok
    if isinstance(event, Gap):
        stream.refused(event.k, now)
    else:
        stream.new_run(event.k, event.line)
    return False


# -- offline: a bag through the join ------------------------------------------------------------


@dataclass(frozen=True)
class AdaptedStreams(Series):
    """A bag's robot topics as the monitor's samples (:func:`read_adapted`): a
    :class:`~fd_monitor.wire.series.Series` (``name`` the bag, ``inputs``/``outputs`` the
    channels, ``k`` (K,) int64 sample indices (gaps are holes), ``u`` (K, nu), ``y``
    (K, ny), ``sample_time`` s: given, the plant's, or the clock's median step snapped to a
    round value) with the adapter's time base.

    Attributes
    ----------
    t : numpy.ndarray
        (K,) s since the first sample (the grid instants).
    clock_topic : str
        The sample clock's topic.
    errors : list of (str, str)
        ``(kind, line)`` per message left out and first of each kind of note
        (:attr:`AdapterJoin.errors`).
    gaps : list of (int, str, str)
        ``(k, reason, channel)`` per sample not usable (``stale``, ``no_value``).
    new_runs : list of int
        First sample of each new run (a clock jump).
    counts : dict
        :meth:`AdapterJoin.counts`.
    sample_time_note : str
        One line: where the sample time came from.
    """

    #: always known here (given, the plant's, or from the clock), unlike a Series'
    sample_time: float = 0.0
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    clock_topic: str = ""
    errors: list[tuple[str, str]] = field(default_factory=list)
    gaps: list[tuple[int, str, str]] = field(default_factory=list)
    new_runs: list[int] = field(default_factory=list)
    counts: dict[str, Any] = field(default_factory=dict)
    sample_time_note: str = ""
    events: list[tuple[float, Any]] = field(default_factory=list, repr=False)

    @property
    def bag(self) -> str:
        """The bag read (:attr:`name`)."""
        return self.name


def stamp_sample_time(stamps_ns: Sequence[int], topic: str) -> tuple[float, str]:
    """Ts from a clock topic's stamps: the median positive step snapped to the round value a
    driver would use (within 1 %, :func:`~fd_monitor.wire.timebase.snap_sample_time`), and
    one line saying so."""
    d = np.diff(np.sort(np.asarray(stamps_ns, dtype=np.int64)))
    d = d[d > 0]
    if d.size == 0:
        raise BagError(f"fewer than two distinct stamps on {topic}: cannot tell the sample time")
    med = float(np.median(d)) * 1e-9
    ts, snapped = snap_sample_time(med)
    if snapped:
        return ts, (f"sample time {ts:g} s ({1 / ts:g} Hz): the median step {med:.9g} s of "
                    f"{topic} snapped to a round value (override with --sample-time)")
    return ts, (f"sample time {ts:.9g} s: the median step of {topic}, no round value within "
                f"1 % (override with --sample-time)")


def read_adapted(bag: str | Path, adapter: Adapter | str | Path,
                 sample_time: float | None = None, system: Any = None) -> AdaptedStreams:
    """Read a robot's bag through an adapter: the samples the live node would process.

    The messages go, in log-time order with the log time as ``now``, through
    :class:`AdapterJoin` (the live node's code); see :mod:`fd_monitor.wire.timebase`, and
    :func:`adapted_events` (the same, one event at a time, in bounded memory).

    Parameters
    ----------
    bag : str or pathlib.Path
    adapter : Adapter, or its file
    sample_time : float, optional
        s; default the plant's (``system``), else the clock's median step snapped to a round
        value (:func:`stamp_sample_time`).
    system : System, optional
        Orders the channels as the plant's (and checks they are the plant's).

    Raises
    ------
    BagError
        A mapped topic missing from the bag or recorded as another type; no sample.
    AdapterError
        Bad adapter file, or channels that are not the plant's.
    """
    run = adapted_events(bag, adapter, sample_time, system)
    events = list(run.events)
    samples = [e for _, e in events if isinstance(e, AdaptedSample)]
    ad = run.adapter
    t0 = samples[0].t_ns
    return AdaptedStreams(
        str(bag), tuple(c.name for c in ad.inputs), tuple(c.name for c in ad.outputs),
        np.array([s.k for s in samples], dtype=np.int64),
        np.array([s.u for s in samples]).reshape(len(samples), len(ad.inputs)),
        np.array([s.y for s in samples]).reshape(len(samples), len(ad.outputs)),
        run.sample_time, np.array([(s.t_ns - t0) * 1e-9 for s in samples]),
        ad.clock_topic, run.errors,
        [(e.k, e.reason, e.channel) for _, e in events if isinstance(e, Gap)],
        [e.k for _, e in events if isinstance(e, NewRun)], run.counts, run.note, events)


@dataclass
class AdaptedRun:
    """:func:`adapted_events`' result: ``events`` yields ``(now, event)`` as the bag is read;
    ``errors`` and ``counts`` are filled when it is exhausted.

    Attributes
    ----------
    adapter : Adapter
        For the plant's channels when a system was given.
    sample_time : float
        s.
    note : str
        Where the sample time came from.
    events : iterator
        ``(now s, AdaptedSample | Gap | NewRun)`` in order (``now = inf``: at the end).
    errors : list of (str, str)
        :meth:`AdapterJoin.take_errors`, at the end.
    counts : dict
        :meth:`AdapterJoin.counts`, at the end.
    """

    adapter: Adapter
    sample_time: float
    note: str
    events: Iterator[tuple[float, Any]] = field(default_factory=lambda: iter(()))
    errors: list[tuple[str, str]] = field(default_factory=list)
    counts: dict[str, Any] = field(default_factory=dict)


def adapted_events(bag: str | Path, adapter: Adapter | str | Path,
                   sample_time: float | None = None, system: Any = None) -> AdaptedRun:
    """:func:`read_adapted`'s events one at a time, in memory that does not grow with the
    bag: the records' log times are read first (8 bytes a record), then the messages are
    read again and put in log-time order through a heap that holds only the ones a later
    record could still precede (a recorder writes one topic's backlog before the next's).
    Without ``sample_time`` and ``system`` the clock topic's stamps are read first too.

    Raises
    ------
    BagError, AdapterError
        As :func:`read_adapted` (a missing topic, a type other than the adapter's, before
        the first event; no sample, when the events are exhausted).
    """
    ad = adapter if isinstance(adapter, Adapter) else load_adapter(adapter)
    note = ""
    if system is not None:
        ad = ad.for_system(system)
        if sample_time is None:
            sample_time = float(system.sample_time)
            note = f"sample time {sample_time:g} s: the plant's ({system.name})"
    elif sample_time is not None:
        note = f"sample time {sample_time:g} s: given"
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    want = ad.topics
    times = array("q")
    stamps = array("q")
    for topic, ty, t, raw in read_raw(bag, list(want)):
        if ty != want[topic]:
            raise BagError(f"{bag}: {topic} is recorded as {ty}, the adapter "
                           f"{ad.source} maps it as {want[topic]}")
        times.append(t)
        if sample_time is None and topic == ad.clock_topic:
            for _tp, tt, msg in messages_from_raw(bag, [(topic, ty, t, raw)]):
                with contextlib.suppress(AttributeError, TypeError, ValueError):
                    stamps.append(_stamp_ns(msg) if ad.header_topic(topic) else tt)
    if sample_time is None:
        try:
            sample_time, note = stamp_sample_time(stamps, ad.clock_topic)
        except BagError as exc:
            raise BagError(f"{bag}: {exc}") from None
    del stamps
    # after record i, a buffered record of log time <= the least later log time is next
    later = np.minimum.accumulate(np.asarray(times, np.int64)[::-1])[::-1]
    later = np.append(later[1:], np.iinfo(np.int64).max)
    del times
    run = AdaptedRun(ad, float(sample_time), note)

    def events() -> Iterator[tuple[float, Any]]:
        join = AdapterJoin(ad, float(sample_time))
        heap: list[tuple[int, int, tuple[str, str, int, bytes]]] = []
        got = False
        for i, rec in enumerate(read_raw(bag, list(want))):
            heapq.heappush(heap, (rec[2], i, rec))
            while heap and heap[0][0] <= later[i]:
                for topic, t, msg in messages_from_raw(bag, [heapq.heappop(heap)[2]]):
                    now = t * 1e-9
                    join.put(topic, msg, t, now)
                    for e in join.events():
                        got = got or isinstance(e, AdaptedSample)
                        yield now, e
        join.advance(None)
        for e in join.events(final=True):
            got = got or isinstance(e, AdaptedSample)
            yield math.inf, e
        run.errors = join.take_errors()
        run.counts = join.counts()
        if not got:
            raise BagError(f"{bag}: no sample from {ad.clock_topic} through {ad.source}"
                           + (f" ({run.errors[0][1]})" if run.errors else ""))

    run.events = events()
    return run


# -- encoding: (u, y) as the robot's messages ----------------------------------------------


def encode(adapter: Adapter, stamp_ns: int, u: Sequence[float], y: Sequence[float],
           make: Callable[..., Any]) -> list[tuple[str, str, Any]]:
    """The robot's messages carrying one sample: ``[(topic, msgtype, message)]``, the
    measurement's topics first: as in a real loop, the measurement y_k is read, then the
    command u_k answering it is sent (the time base places both in sample k).

    Parameters
    ----------
    adapter : Adapter
        Channels in the order of ``u`` and ``y``.
    stamp_ns : int
        Header stamp, ns.
    u, y : sequence of float
    make : callable
        ``make(msgtype, **fields)`` -> a message (rosbags: ``typestore.types[t](**f)``;
        rclpy: the message class called with the fields). Nested fields are built with it
        too (``std_msgs/msg/Header``, ``builtin_interfaces/msg/Time``, ...).
    """
    vals = {c.name: float(v) for c, v in zip(adapter.inputs, u)}
    vals.update({c.name: float(v) for c, v in zip(adapter.outputs, y)})
    by_topic: dict[str, list[Channel]] = {}
    for c in (*adapter.outputs, *adapter.inputs):
        by_topic.setdefault(c.topic, []).append(c)
    out = []
    for topic, chans in by_topic.items():
        ty = chans[0].msgtype
        out.append((topic, ty, _build(ty, chans, vals, stamp_ns, make)))
    return out


def _header(stamp_ns: int, make: Callable[..., Any]) -> Any:
    t = make("builtin_interfaces/msg/Time", sec=int(stamp_ns // 1_000_000_000),
             nanosec=int(stamp_ns % 1_000_000_000))
    return make("std_msgs/msg/Header", stamp=t, frame_id="")


def _vec(make: Callable[..., Any], ty: str, v: Mapping[str, float], keys: Iterable[str]
         ) -> Any:
    return make(ty, **{k: float(v.get(k, 0.0)) for k in keys})


def _build(ty: str, chans: Sequence[Channel], vals: Mapping[str, float], stamp_ns: int,
           make: Callable[..., Any]) -> Any:
    if ty == "std_msgs/msg/Float64":
        return make(ty, data=vals[chans[0].name])
    if ty == "std_msgs/msg/Float64MultiArray":
        if any(c.label for c in chans):
            labels = [c.label or str(c.index) for c in chans]
            data = [vals[c.name] for c in chans]
        else:
            n = max(c.index for c in chans) + 1
            data = [0.0] * n
            for c in chans:
                data[c.index] = vals[c.name]
            labels = []
        dims = ([make("std_msgs/msg/MultiArrayDimension", label=",".join(labels),
                      size=len(data), stride=len(data))] if labels else [])
        layout = make("std_msgs/msg/MultiArrayLayout", dim=dims, data_offset=0)
        return make(ty, layout=layout, data=np.asarray(data, dtype=np.float64))
    if ty == "sensor_msgs/msg/JointState":
        joints = list(dict.fromkeys(c.joint for c in chans))
        arrays = {f: np.zeros(len(joints)) for f in ("position", "velocity", "effort")}
        used = {c.field for c in chans}
        for c in chans:
            arrays[c.field][joints.index(c.joint)] = vals[c.name]
        return make(ty, header=_header(stamp_ns, make), name=joints,
                    **{f: (a if f in used else np.zeros(0)) for f, a in arrays.items()})
    # Odometry, Twist, TwistStamped: nested vectors of the mapped leaves, zeros elsewhere
    leaf = {c.field: vals[c.name] for c in chans}
    if "yaw" in leaf:
        yaw = leaf.pop("yaw")
        leaf["pose.pose.orientation.z"] = math.sin(yaw / 2.0)
        leaf["pose.pose.orientation.w"] = math.cos(yaw / 2.0)

    def sub(prefix: str) -> dict[str, float]:
        return {k[len(prefix):]: v for k, v in leaf.items() if k.startswith(prefix)}

    def twist(prefix: str) -> Any:
        return make("geometry_msgs/msg/Twist",
                    linear=_vec(make, "geometry_msgs/msg/Vector3", sub(prefix + "linear."), _VEC),
                    angular=_vec(make, "geometry_msgs/msg/Vector3", sub(prefix + "angular."),
                                 _VEC))

    if ty == "geometry_msgs/msg/Twist":
        return twist("")
    if ty == "geometry_msgs/msg/TwistStamped":
        return make(ty, header=_header(stamp_ns, make), twist=twist("twist."))
    o = sub("pose.pose.orientation.")
    o.setdefault("w", 1.0)
    pose = make("geometry_msgs/msg/Pose",
                position=_vec(make, "geometry_msgs/msg/Point", sub("pose.pose.position."),
                              _VEC),
                orientation=_vec(make, "geometry_msgs/msg/Quaternion", o, (*_VEC, "w")))
    cov = np.zeros(36)
    return make(ty, header=_header(stamp_ns, make), child_frame_id="",
                pose=make("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=cov),
                twist=make("geometry_msgs/msg/TwistWithCovariance", twist=twist("twist.twist."),
                           covariance=cov.copy()))


def rosbags_make(msgtype: str, **fields: Any) -> Any:
    """:func:`encode`'s ``make`` for bags: the ``rosbags`` ROS 2 Jazzy dataclass."""

    return _typestore().types[msgtype](**fields)


def write_adapted(writer: Any, adapter: Adapter, k: Sequence[int], u: np.ndarray,
                  y: np.ndarray, stamps_ns: Sequence[int]) -> None:
    """Write samples as the robot's messages into an open
    :class:`~fd_monitor.wire.bag_writer.BagWriter` (``simulate --adapter``): per sample the
    outputs' topics, then the inputs' (:func:`encode`), header stamps and bag times
    ``stamps_ns``.

    Parameters
    ----------
    writer : BagWriter
    adapter : Adapter
        Channels in the order of the columns of ``u`` and ``y``.
    k : sequence of int
        (K,) sample indices (only their count is used: one message set per sample).
    u, y : numpy.ndarray
        (K, nu), (K, ny)
    stamps_ns : sequence of int
        (K,) ns.
    """

    store = _typestore()
    for topic, ty in adapter.topics.items():
        writer.add_topic(topic, ty)
    for i in range(len(k)):
        t = int(stamps_ns[i])
        for topic, ty, msg in encode(adapter, t, u[i], y[i], rosbags_make):
            writer.write_raw(topic, t, bytes(store.serialize_cdr(msg, ty)))
