"""Which Fast DDS profile a process loads: the nodes cap their readers, record does not, a
user's own profile file is kept."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

from ros_util import REPO

from fd_monitor.nodes.common import _PROFILE_VARS, use_dds_profile

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"


def _reader_cap(path: str) -> int | None:
    node = ET.parse(path).getroot().find(f"{NS}data_reader/{NS}topic/{NS}resourceLimitsQos/"
                                         f"{NS}max_samples")
    return None if node is None else int(node.text or 0)


def test_nodes_cap_readers_record_does_not_user_profile_kept(monkeypatch, tmp_path):
    for var in _PROFILE_VARS:
        monkeypatch.delenv(var, raising=False)
    nodes = use_dds_profile()
    assert nodes == str(REPO / "config/fastdds.xml") and _reader_cap(nodes) == 2000
    # a record started by a process that loaded the nodes' profile switches to its own
    rec = use_dds_profile("fastdds_record.xml")
    assert rec == str(REPO / "config/fastdds_record.xml") and _reader_cap(rec) is None
    assert all(os.environ[v] == rec for v in _PROFILE_VARS)
    mine = tmp_path / "mine.xml"
    mine.write_text("<profiles/>")
    for var in _PROFILE_VARS:
        monkeypatch.setenv(var, str(mine))
    assert use_dds_profile("fastdds_record.xml") == str(mine)
