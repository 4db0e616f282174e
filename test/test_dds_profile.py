"""Which Fast DDS profile a process loads (nodes: 20 ms heartbeats; pacing sources: 2 ms)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from fd_monitor.model.paths import config_dirs

VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def heartbeat_s(xml: str) -> float:
    period = ET.parse(xml).getroot().find("p:data_writer/p:times/p:heartbeatPeriod", NS)
    assert period is not None
    return (int(period.find("p:sec", NS).text) + int(period.find("p:nanosec", NS).text) * 1e-9)


@pytest.fixture
def clean_env(monkeypatch):
    for v in VARS:
        monkeypatch.delenv(v, raising=False)
    return monkeypatch


def test_nodes_and_pacing_sources_get_their_profiles(clean_env):
    from fd_monitor.nodes.pacing import use_dds_profile

    nodes = use_dds_profile()
    assert Path(nodes).name == "fastdds.xml" and heartbeat_s(nodes) == pytest.approx(0.02)
    # a child of a node process (the variable inherited) that paces chooses again
    pacing = use_dds_profile(pacing=True)
    assert Path(pacing).name == "fastdds_pacing.xml"
    assert heartbeat_s(pacing) == pytest.approx(0.002)
    import os

    assert all(os.environ[v] == pacing for v in VARS)
    assert Path(use_dds_profile()).name == "fastdds.xml"


def test_a_users_profile_is_kept(clean_env, tmp_path):
    from fd_monitor.nodes.pacing import use_dds_profile

    mine = tmp_path / "mine.xml"
    mine.write_text((next(iter(config_dirs())) / "fastdds.xml").read_text())
    clean_env.setenv(VARS[0], str(mine))
    assert use_dds_profile(pacing=True) == str(mine)
    assert use_dds_profile() == str(mine)
