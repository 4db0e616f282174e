"""Bags you can trust (issue 12): chunk CRCs checked on read, damage reported by byte
position (never silently changed data), bags whose writer died read and recovered."""

from __future__ import annotations

import subprocess
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from fd_monitor.analysis.library import load_library
from fd_monitor.commands.simulate import simulate_to_bag
from fd_monitor.model.errors import BagError
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.bag_scanner import BagDamageWarning, bag_topics, read_raw
from fd_monitor.wire.bag_writer import BagWriter, serialize_array

REPO = Path(__file__).resolve().parent.parent


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fd_monitor", *args], capture_output=True,
                          text=True, timeout=120, cwd=REPO)


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    """three_tank_bias_h1, 60 s (600 samples of u, y, truth), written by `simulate`."""
    path = tmp_path_factory.mktemp("integrity") / "sim"
    simulate_to_bag("three_tank_bias_h1", path, seed=4, duration=60.0)
    return path


@pytest.fixture(scope="module")
def small_chunks(sim_bag, tmp_path_factory):
    """The same messages in 8 KiB chunks (about 20 chunks): bit flips hit every part."""
    path = tmp_path_factory.mktemp("integrity") / "small"
    with BagWriter(path, chunk_bytes=8 * 1024) as w:
        for topic, ty, t, data in read_raw(sim_bag):
            w.add_topic(topic, ty)
            w.write_raw(topic, t, data)
    return path


def _messages(path, damage=None):
    return [(topic, t, data) for topic, _ty, t, data in read_raw(path, damage=damage)]


def test_written_bags_check_clean_and_rosbags_reads_them(sim_bag):
    """Every chunk carries a CRC; rosbags (another reader) gets the same messages."""
    from rosbags.rosbag2 import Reader

    damage: list = []
    ours = _messages(sim_bag, damage)
    assert damage == [] and len(ours) == 1800
    with open(next(sim_bag.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == 1800
    with Reader(sim_bag) as r:
        theirs = [(c.topic, t, bytes(d)) for c, t, d in r.messages()]
    assert theirs == ours


def test_library_bags_have_chunk_crcs_and_no_damage():
    for spec in load_library().bags:
        damage: list = []
        n = sum(1 for _ in read_raw(spec.folder, damage=damage))
        assert n > 0 and damage == [], (spec.name, [str(d) for d in damage])


def test_150_bit_flips_are_never_silent(small_chunks, tmp_path):
    """Each of 150 single-bit flips spread over the file: the messages read are original
    messages in their order, and if any is missing the damage was reported (by byte)."""
    src = next(small_chunks.glob("*.mcap"))
    data = src.read_bytes()
    original = _messages(small_chunks)
    rng = np.random.default_rng(12)
    positions = np.sort(rng.choice(len(data), size=150, replace=False))
    silent, reported, harmless = [], 0, 0
    bad = tmp_path / "flipped.mcap"
    for pos in positions:
        flipped = bytearray(data)
        flipped[pos] ^= 1 << int(rng.integers(8))
        bad.write_bytes(bytes(flipped))
        damage: list = []
        try:
            got = _messages(bad, damage)
        except BagError as exc:     # the leading magic: not an MCAP file at all
            assert pos < 8 and "not an MCAP file" in str(exc)
            reported += 1
            continue
        # never changed data: what is read is a subsequence of the original messages
        it = iter(original)
        assert all(m in it for m in got), f"flip at byte {pos}: changed data was returned"
        if got != original and not damage:
            silent.append(int(pos))
        reported += bool(damage)
        harmless += got == original and not damage
        # a damaged chunk loses its own messages only: the rest of the bag is read
        assert len(got) >= len(original) - 200, (pos, len(got), [str(d) for d in damage])
        assert all(f"byte {d.offset}" in str(d) for d in damage)
    assert silent == []
    assert reported >= 100, (reported, harmless)   # most flips land in chunk data


def test_random_bytes_inside_a_chunk_one_line(sim_bag, tmp_path):
    """200 random bytes inside one chunk (was: ZstdError traceback): `analyze` warns with
    one line naming the byte, reads the rest and finishes; `bag check` exits 1."""
    import shutil

    bag = tmp_path / "junk"
    shutil.copytree(sim_bag, bag)
    f = next(bag.glob("*.mcap"))
    with open(f, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    c = chunks[1]
    assert c.chunk_length > 600
    buf = bytearray(f.read_bytes())
    at = c.chunk_start_offset + 300
    buf[at:at + 200] = np.random.default_rng(3).bytes(200)
    f.write_bytes(bytes(buf))
    out = cli("analyze", str(bag), "--gains", "three_tank_thresholds", "--json")
    assert out.returncode == 0, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fd_monitor: warning: "), out.stderr
    assert f"byte {c.chunk_start_offset}:" in lines[0] and "skipped" in lines[0]
    assert "Traceback" not in out.stderr
    chk = cli("bag", "check", str(bag))
    assert chk.returncode == 1 and f"byte {c.chunk_start_offset}" in chk.stdout


def test_wrong_message_type_is_one_line(tmp_path):
    """/plant/y recorded as std_msgs/String: one line naming the topic and its type."""
    from fd_monitor.wire.bag_reader import _typestore

    store = _typestore()
    bag = tmp_path / "strings"
    with BagWriter(bag) as w:
        w.add_topic("/plant/u")
        w.add_topic("/plant/y", "std_msgs/msg/String")
        for k in range(20):
            w.write_raw("/plant/u", k, serialize_array(("q1", "q2", "v13"), k, [0, 0, 0]))
            w.write_raw("/plant/y", k, bytes(store.serialize_cdr(
                store.types["std_msgs/msg/String"](data=f"{k}"), "std_msgs/msg/String")))
    out = cli("analyze", str(bag), "--gains", "three_tank_thresholds")
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "/plant/y is std_msgs/msg/String, not std_msgs/msg/Float64MultiArray" in lines[0]
    with pytest.raises(BagError, match="/plant/y is std_msgs/msg/String"):
        read_bag(bag, ["/plant/y"])


def _die_while_writing(path: Path, n: int) -> None:
    """A writer process that flushes chunks and is then killed (os._exit: no close)."""
    code = f"""
import os
from fd_monitor.wire.bag_writer import BagWriter
w = BagWriter({str(path)!r}, chunk_bytes=4096)
for k in range({n}):
    w.write_array("/plant/y", k, ("h1", "h2", "h3"), [0.1, 0.2, 0.3], k * 1_000_000)
os._exit(9)
"""
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, timeout=60)
    assert r.returncode == 9


def test_bag_of_a_dead_writer_is_read_and_recovered(tmp_path):
    bag = tmp_path / "dead"
    _die_while_writing(bag, 2000)
    assert not (bag / "metadata.yaml").exists()
    damage: list = []
    got = _messages(bag, damage)
    # only the chunk being filled is lost (4 KiB: ~40 messages)
    assert 2000 - 60 <= len(got) < 2000
    assert [t for _, t, _ in got] == [k * 1_000_000 for k in range(len(got))]
    assert len(damage) == 1 and "the writer did not close the bag" in str(damage[0])
    with pytest.warns(BagDamageWarning, match="did not close"):
        assert bag_topics(bag) == {"/plant/y": ("std_msgs/msg/Float64MultiArray", len(got))}
    out = cli("bag", "recover", str(bag), "-o", str(tmp_path / "fixed"), "--json")
    assert out.returncode == 0, out.stderr
    assert "fd_monitor: warning:" in out.stderr and "did not close" in out.stderr
    fixed: list = []
    assert _messages(tmp_path / "fixed", fixed) == got and fixed == []
    assert (tmp_path / "fixed" / "metadata.yaml").is_file()
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "fixed") as r:
        assert sum(1 for _ in r.messages()) == len(got)
    again = cli("bag", "recover", str(bag), "-o", str(tmp_path / "fixed"))
    assert again.returncode == 2 and "already exists" in again.stderr


def test_analyze_reads_a_bag_whose_recorder_died(sim_bag, tmp_path):
    """No footer, no metadata.yaml: `analyze` runs on what was written (one warning)."""
    import shutil

    bag = tmp_path / "cut"
    shutil.copytree(sim_bag, bag)
    (bag / "metadata.yaml").unlink()
    f = next(bag.glob("*.mcap"))
    with open(f, "rb") as fh:
        last = make_reader(fh).get_summary().chunk_indexes[-1]
    f.write_bytes(f.read_bytes()[:last.chunk_start_offset + 100])   # died mid-chunk
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BagDamageWarning)
        n_y = Counter(t for t, *_ in _messages(bag))["/plant/y"]
    assert 0 < n_y < 600
    out = cli("analyze", str(bag), "--gains", "three_tank_thresholds", "--json")
    assert out.returncode == 0, out.stderr
    assert "incomplete" in out.stderr and "Traceback" not in out.stderr


def test_not_a_bag_is_one_line(tmp_path):
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "b.mcap").write_bytes(b"hello, this is not an mcap file at all")
    with pytest.raises(BagError, match="not an MCAP file"):
        bag_topics(tmp_path / "b")
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "e.mcap").write_bytes(b"")
    with pytest.raises(BagError, match=r"empty file \(0 bytes\)"):
        bag_topics(tmp_path / "e")
