"""The checks of a bag's input that every reader shares (below :mod:`fd_monitor.analysis`):
``metadata.yaml`` against its MCAP, the label limits of offline reading, and the integrity
record of what was not used (see :mod:`fd_monitor.analysis.integrity` for the contract).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fd_monitor.model.errors import BagError, FdMonitorError
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["MAX_DISTINCT_LABELS", "MAX_LABEL_CHARS", "describe", "integrity",
           "metadata_problems"]

#: Longest channel-label string (``layout.dim[0].label``) of a message read offline,
#: characters; a longer one is refused as ``malformed`` (a label is a few channel names).
MAX_LABEL_CHARS = 4096
#: Most distinct label strings on one topic of a bag; beyond it the bag is refused (one
#: topic carries one plant's channels: a few layouts at most, never thousands).
MAX_DISTINCT_LABELS = 64

#: Kinds of input errors that refuse a received sample (its stamp is lost).
_REFUSED = ("non_finite", "wrong_length", "malformed", "implausible")
#: Kinds that drop a message without losing a sample.
_DROPPED = ("duplicate", "out_of_order", "late", "held", "dropped", "stray", "decimated")


def metadata_problems(bag: str | Path, present: Mapping[str, tuple[str, int]],
                      damaged: bool = False) -> list[str]:
    """Where a bag folder's ``metadata.yaml`` disagrees with the MCAP it names.

    Parameters
    ----------
    bag : str or pathlib.Path
        The bag folder (an ``.mcap`` given directly has no metadata: nothing to compare).
    present : mapping
        topic -> (message type, messages read) of the MCAP.
    damaged : bool
        Messages were lost to damage: fewer read than listed is then expected, not said.

    Returns
    -------
    list of str
        One line each (empty: they agree).
    """
    p = Path(bag)
    if not p.is_dir():
        return []
    meta = p / "metadata.yaml"
    if not meta.is_file():
        return ["no metadata.yaml (its writer died, or it was removed): the topics, types and "
                "counts of the .mcap cannot be cross-checked"]
    try:
        info = read_yaml(meta, BagError)["rosbag2_bagfile_information"]
        listed = {str(e["topic_metadata"]["name"]): (str(e["topic_metadata"]["type"]),
                                                     int(e["message_count"]))
                  for e in info.get("topics_with_message_count") or []}
        total = int(info.get("message_count", sum(n for _t, n in listed.values())))
        files = [str(f.get("path")) for f in info.get("files") or [] if isinstance(f, Mapping)]
        rel = [str(f) for f in info["relative_file_paths"]]
    except (FdMonitorError, KeyError, TypeError, ValueError, AttributeError) as exc:
        return [f"metadata.yaml unreadable ({str(exc).splitlines()[0][:200]})"]
    out: list[str] = []
    if files and files != rel:
        out.append(f"metadata.yaml: files {files} but relative_file_paths {rel}")
    for t in sorted(set(listed) | set(present)):
        if t not in present:
            if listed[t][1] and not damaged:
                out.append(f"metadata.yaml lists {t} ({listed[t][1]} messages), the .mcap has "
                           f"no message on it")
            continue
        ty, n = present[t]
        if t not in listed:
            out.append(f"the .mcap has {t} ({n} messages), metadata.yaml does not list it")
            continue
        if listed[t][0] != ty:
            out.append(f"{t}: metadata.yaml says type {listed[t][0]}, the .mcap {ty}")
        if listed[t][1] != n and (n > listed[t][1] or not damaged):
            out.append(f"{t}: metadata.yaml says {listed[t][1]} messages, the .mcap has {n}")
    read = sum(n for _t, n in present.values())
    if total != read and (read > total or not damaged):
        out.append(f"metadata.yaml says {total} messages in all, the .mcap has {read}")
    return out


def integrity(scan: Any, rep: Any = None) -> dict[str, Any]:
    """The integrity record of a bag read by ``scan`` (a
    :class:`~fd_monitor.analysis.offline.BagScan`) and, when samples were read, their
    :class:`~fd_monitor.analysis.offline.InputReport` (see the module docstring)."""
    damage = [d for d in scan.damage if d.kind == "damage"]
    unchecked = sum(int(str(d.what).split()[0]) for d in scan.damage if d.kind != "damage")
    doc: dict[str, Any] = {"clean": True, "skipped_chunks": len(damage),
                           "damage": [str(d) for d in damage], "unchecked_chunks": unchecked,
                           "metadata": list(scan.metadata)}
    refused: dict[str, int] = {}
    dropped: dict[str, int] = {}
    if rep is not None:
        counts = rep.sample_counts()
        skipped = dict(counts["skipped"])
        doc.update(samples_present=counts["present"], samples_used=counts["used"],
                   lost_samples=counts["present"] - counts["used"], samples_skipped=skipped)
        refused = {k: v for k, v in skipped.items() if k in _REFUSED}
        for e in rep.errors:
            if e["kind"] in _DROPPED:
                dropped[e["kind"]] = dropped.get(e["kind"], 0) + 1
    doc["refused_samples"] = refused
    doc["dropped_messages"] = dict(sorted(dropped.items()))
    doc["clean"] = not (damage or doc["metadata"] or doc.get("lost_samples") or refused
                        or dropped)
    return doc


def describe(doc: Mapping[str, Any]) -> str:
    """One line: what of the bag was not used (``doc`` from :func:`integrity`)."""
    parts = []
    if doc["skipped_chunks"]:
        parts.append(f"{doc['skipped_chunks']} damaged region(s) skipped")
    if doc.get("lost_samples"):
        parts.append(f"{doc['lost_samples']} of {doc['samples_present']} samples not used ("
                     + ", ".join(f"{k} {n}" for k, n in doc["samples_skipped"].items()) + ")")
    if doc["dropped_messages"]:
        parts.append("messages dropped: " + ", ".join(f"{k} {n}" for k, n in
                                                      doc["dropped_messages"].items()))
    if doc["metadata"]:
        parts.append(f"metadata.yaml disagrees with the MCAP: {doc['metadata'][0]}"
                     + (f" (and {len(doc['metadata']) - 1} more)"
                        if len(doc["metadata"]) > 1 else ""))
    return "; ".join(parts) or "every message and sample used"
