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

Timing. A message's time is its ``header.stamp`` where the type has a header (JointState,
Odometry, TwistStamped) and the stamp is not zero, else its receive time (bag time offline).
The **sample clock** is the first output's topic: every message there is one sample, with
index ``k = round((t - t0) / Ts)`` (``t0`` the first sample's time, ``Ts`` the plant's sample
time), so a missing message is a hole in k and two messages within Ts/2 are a duplicate.
Every other channel (inputs, outputs on other topics) is **held** (zero-order hold): a
sample takes the latest value received before it (its header stamp at or before the
sample's, when both topics carry header stamps). A sample with a held channel never received
yet is reported and skipped, as the nodes' pairing rule does for a plain ``plant/y``.

Pure: decoding reads attributes of already deserialised messages, so the same code decodes
the dataclasses ``rosbags`` reads from a bag and rclpy's messages; nothing here imports rclpy.
:class:`AdapterJoin` is the one join (time is an argument): :func:`read_adapted` runs it over
a bag (``analyze --adapter``, ``identify --adapter``), the nodes run it live
(:mod:`fd_monitor.nodes.adapter_input`), :func:`encode` builds the robot's messages from
(u, y) (``simulate --adapter``, ``plant_sim -p adapter:=``).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.model.errors import BagError, FdMonitorError, MessageError
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.system import read_yaml
from fd_monitor.wire.bags import _typestore, messages_from_raw, read_raw

__all__ = ["ADAPTER_TYPES", "Adapter", "AdapterError", "AdapterJoin", "AdaptedMessageError",
           "AdaptedSample", "AdaptedStreams", "Channel", "Reading", "decode_message", "encode",
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

#: Messages kept per held topic while no sample uses them.
MAX_HELD = 10_000

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
    """

    name: str
    topic: str
    msgtype: str
    field: str = ""
    joint: str = ""
    label: str = ""
    index: int = -1

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
    """

    source: str
    inputs: tuple[Channel, ...]
    outputs: tuple[Channel, ...]
    clock_topic: str = ""

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

        return Adapter(self.source, order(self.inputs, system.inputs, "inputs"),
                       order(self.outputs, system.outputs, "outputs"), self.clock_topic)


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
    unknown = sorted(set(doc) - {"format_version", "description", "inputs", "outputs"})
    if unknown:
        raise AdapterError(f"{source}: {unknown[0]}: unknown key (expected format_version, "
                           f"description, inputs, outputs)")
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
    return Adapter(source, chans["inputs"], chans["outputs"])


def _channel(item: Any, where: str) -> Channel:
    if not isinstance(item, Mapping):
        raise AdapterError(f"{where}: expected a mapping {{channel, topic, type, ...}}, got "
                           f"{item!r}")
    allowed = {"channel", "topic", "type", "field", "joint", "label", "index"}
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
        return Channel(name, topic, ty, "", "", label, int(index))
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
    return Channel(name, topic, ty, fld, joint)


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
            stamp = _stamp_ns(msg)
            at = f"{topic} stamp {stamp * 1e-9:.3f} s"
            if stamp == 0:
                header, stamp = False, receive_ns
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
        The sample clock's time (header stamp or receive time), ns.
    u, y : numpy.ndarray
        (nu,), (ny,) in the plant's (the adapter's) channel order.
    """

    k: int
    t_ns: int
    u: np.ndarray
    y: np.ndarray


class AdapterJoin:
    """Turn the robot's messages into samples (k, u, y): the sample clock and the hold.

    Pure; time is an argument. :meth:`put` one message at a time (in arrival order, or bag
    order offline); :meth:`ready` releases the samples that are complete: a clock message
    whose held channels are known, i.e. every held topic has delivered a message after it
    (so the latest one before it is in), or ``hold_wait`` s have passed since it arrived, or
    ``now`` is None (offline: every message is in).

    Parameters
    ----------
    adapter : Adapter
        Channels in the order u and y are built in (:meth:`Adapter.for_system`).
    sample_time : float
        s between samples of the clock (the plant's Ts).
    hold_wait : float
        s a sample waits for a later message of each held topic.
    """

    def __init__(self, adapter: Adapter, sample_time: float, hold_wait: float = 0.1) -> None:
        if not sample_time > 0:
            raise AdapterError(f"{adapter.source}: sample time {sample_time!r}: expected > 0")
        self.adapter = adapter
        self.ts_ns = float(sample_time) * 1e9
        self.hold_wait = float(hold_wait)
        self.clock = adapter.clock_topic
        held = [c for c in (*adapter.outputs, *adapter.inputs) if c.topic != self.clock]
        self.held_topics = tuple(dict.fromkeys(c.topic for c in held))
        # compare header stamps only when the clock and the held topic both carry them
        self._by_stamp = {t: adapter.header_topic(t) and adapter.header_topic(self.clock)
                          for t in self.held_topics}
        self._held: dict[str, list[tuple[int, int, dict[str, float]]]] = {
            t: [] for t in self.held_topics}
        self._last: dict[str, int] = {}
        self._waiting: list[tuple[Reading, float | None]] = []
        self.t0: int | None = None
        self.k_last: int | None = None
        self.stamp_ok = True
        #: ``(kind, line)`` per message or sample left out (kinds as the offline report's:
        #: non_finite, malformed, duplicate, out_of_order, missing).
        self.errors: list[tuple[str, str]] = []
        self.skipped = 0
        self._seq = 0

    def reset(self) -> None:
        """Forget the stream (a new run starts at the next clock message, k from 0)."""
        self.t0, self.k_last = None, None
        self._waiting.clear()

    def put(self, topic: str, msg: Any, receive_ns: int, now: float | None = None) -> None:
        """Decode one message; a bad one is added to :attr:`errors` (one line) and dropped.

        ``now`` (s, monotonic) is the arrival time for the hold wait (None offline).
        """
        try:
            r = decode_message(self.adapter, topic, msg, receive_ns)
        except AdaptedMessageError as exc:
            self.errors.append((exc.kind, str(exc)))
            return
        self.put_reading(r, now)

    def put_reading(self, r: Reading, now: float | None = None) -> None:
        """Join an already decoded :class:`Reading`."""
        if r.topic == self.clock:
            self._waiting.append((r, now))
        if r.topic in self._held:
            key = r.stamp_ns if self._by_stamp[r.topic] else r.receive_ns
            hist = self._held[r.topic]
            self._seq += 1
            bisect.insort(hist, (key, self._seq, r.values))
            if len(hist) > MAX_HELD:     # no sample for a long time: keep the latest only
                del hist[:len(hist) - MAX_HELD]
            self._last[r.topic] = max(self._last.get(r.topic, key), key)

    def _key(self, topic: str, r: Reading) -> int:
        return r.stamp_ns if self._by_stamp[topic] else r.receive_ns

    def ready(self, now: float | None = None) -> list[AdaptedSample]:
        """Release the complete samples in order (``now`` None: everything, offline)."""
        out: list[AdaptedSample] = []
        while self._waiting:
            r, arrived = self._waiting[0]
            if now is not None and arrived is not None and now - arrived < self.hold_wait:
                if not all(self._last.get(t, -1) > self._key(t, r) for t in self.held_topics):
                    break
            self._waiting.pop(0)
            s = self._sample(r)
            if s is not None:
                out.append(s)
        return out

    def _sample(self, r: Reading) -> AdaptedSample | None:
        values = dict(r.values)
        missing = []
        for t in self.held_topics:
            key = self._key(t, r)
            hist = self._held[t]
            i = bisect.bisect_right(hist, (key, math.inf)) - 1
            if i < 0:
                missing.append(t)
                continue
            values.update(hist[i][2])
            del hist[:i]   # keep the one held at this sample: the next ones may need it
        where = f"{self.clock} stamp {r.stamp_ns * 1e-9:.3f} s"
        if missing:
            self.skipped += 1
            self.errors.append(("missing", f"{where}: no {', '.join(missing)} received "
                                           f"before it; sample skipped"))
            return None
        if self.t0 is None:
            self.t0 = r.stamp_ns
        k = round((r.stamp_ns - self.t0) / self.ts_ns)
        if self.k_last is not None and k == self.k_last:
            self.skipped += 1
            self.errors.append(("duplicate", f"{where}: duplicate sample (within half a "
                                             f"sample time of the previous one); dropped"))
            return None
        if self.k_last is not None and k < self.k_last:
            # the clock went back (a restarted driver, a bag played again): a new stream,
            # numbered on after a one-sample hole, so the monitor restarts there (fresh state)
            # and offline the samples keep increasing indices
            k = self.k_last + 2
            self.t0 = r.stamp_ns - round(k * self.ts_ns)
            self.errors.append(("out_of_order", f"{where}: before the previous sample (the "
                                                f"clock went back): a new stream from k = {k}"))
        self.k_last = k
        a = self.adapter
        return AdaptedSample(k, r.stamp_ns, np.array([values[c.name] for c in a.inputs]),
                             np.array([values[c.name] for c in a.outputs]))

    def take_errors(self) -> list[tuple[str, str]]:
        """The ``(kind, line)`` errors since the last call."""
        out, self.errors = self.errors, []
        return out


# -- offline: a bag through the join ------------------------------------------------------------


@dataclass
class AdaptedStreams:
    """A bag's robot topics as the monitor's samples (:func:`read_adapted`).

    Attributes
    ----------
    bag : str
    inputs, outputs : tuple of str
        Channel names (u and y columns).
    k : numpy.ndarray
        (K,) int64 sample indices (gaps are holes).
    t : numpy.ndarray
        (K,) s since the first sample (the clock's times).
    u, y : numpy.ndarray
        (K, nu), (K, ny)
    sample_time : float
        s (given, or the median spacing of the clock's times).
    clock_topic : str
        The sample clock's topic.
    errors : list of (str, str)
        ``(kind, line)`` per message or sample left out (:attr:`AdapterJoin.errors`).
    """

    bag: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    k: np.ndarray
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    sample_time: float
    clock_topic: str
    errors: list[tuple[str, str]] = field(default_factory=list)


def read_adapted(bag: str | Path, adapter: Adapter | str | Path,
                 sample_time: float | None = None, system: Any = None) -> AdaptedStreams:
    """Read a robot's bag through an adapter: the samples the live node would process.

    Parameters
    ----------
    bag : str or pathlib.Path
    adapter : Adapter, or its file
    sample_time : float, optional
        s; default the plant's (``system``) or the median spacing of the clock's messages.
    system : System, optional
        Orders the channels as the plant's (and checks they are the plant's).

    Raises
    ------
    BagError
        A mapped topic missing from the bag or recorded as another type; no sample.
    AdapterError
        Bad adapter file, or channels that are not the plant's.
    """

    ad = adapter if isinstance(adapter, Adapter) else load_adapter(adapter)
    if system is not None:
        ad = ad.for_system(system)
        if sample_time is None:
            sample_time = float(system.sample_time)
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    want = ad.topics
    records = []
    for rec in read_raw(bag, list(want)):
        if rec[1] != want[rec[0]]:
            raise BagError(f"{bag}: {rec[0]} is recorded as {rec[1]}, the adapter "
                           f"{ad.source} maps it as {want[rec[0]]}")
        records.append(rec)
    errors: list[tuple[str, str]] = []
    readings: list[Reading] = []
    for topic, t, msg in messages_from_raw(bag, records):
        try:
            readings.append(decode_message(ad, topic, msg, t))
        except AdaptedMessageError as exc:
            errors.append((exc.kind, str(exc)))
    clock = np.array([r.stamp_ns for r in readings if r.topic == ad.clock_topic], dtype=float)
    if sample_time is None:
        d = np.diff(np.sort(clock))
        d = d[d > 0]
        if d.size == 0:
            raise BagError(f"{bag}: fewer than two valid messages on {ad.clock_topic}: "
                           f"cannot tell the sample time")
        sample_time = float(np.median(d)) * 1e-9
    join = AdapterJoin(ad, sample_time)
    for r in readings:
        join.put_reading(r)
    samples = join.ready()
    errors += join.take_errors()
    if not samples:
        raise BagError(f"{bag}: no sample from {ad.clock_topic} through {ad.source}"
                       + (f" ({errors[0][1]})" if errors else ""))
    t0 = samples[0].t_ns
    return AdaptedStreams(
        str(bag), tuple(c.name for c in ad.inputs), tuple(c.name for c in ad.outputs),
        np.array([s.k for s in samples], dtype=np.int64),
        np.array([(s.t_ns - t0) * 1e-9 for s in samples]),
        np.array([s.u for s in samples]).reshape(len(samples), len(ad.inputs)),
        np.array([s.y for s in samples]).reshape(len(samples), len(ad.outputs)),
        float(sample_time), ad.clock_topic, errors)


# -- encoding: (u, y) as the robot's messages ----------------------------------------------


def encode(adapter: Adapter, stamp_ns: int, u: Sequence[float], y: Sequence[float],
           make: Callable[..., Any]) -> list[tuple[str, str, Any]]:
    """The robot's messages carrying one sample: ``[(topic, msgtype, message)]``, inputs'
    topics first (a command is sent before the measurement it acts on is read).

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
    for c in (*adapter.inputs, *adapter.outputs):
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
    :class:`~fd_monitor.wire.bags.BagWriter` (``simulate --adapter``): per sample the
    inputs' topics, then the outputs', header stamps and bag times ``stamps_ns``.

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
