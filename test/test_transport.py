"""densecalib_node's own Fast DDS settings (ros.transport): which environments it changes, and
the profile it writes. What they achieve is measured on real processes in test_bench_node."""
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from densecalib_ros.ros import transport
from densecalib_ros.ros.transport import (INTAKE_RECEIVE_BUFFER_BYTES, configure_intake_transport,
                                          receive_buffer_limit)

NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def _profile(environ):
    root = ET.parse(environ["FASTRTPS_DEFAULT_PROFILES_FILE"]).getroot()
    buffer = int(root.find(".//p:transport_descriptor/p:receiveBufferSize", NS).text)
    kind = root.find(".//p:transport_descriptor/p:type", NS).text
    builtin = root.find(".//p:useBuiltinTransports", NS).text
    peers = [a.text for a in root.findall(".//p:initialPeersList//p:address", NS)]
    return kind, builtin, buffer, peers


@pytest.mark.parametrize("range_", ["", "SUBNET", "LOCALHOST"])
def test_the_node_receives_over_udp_with_a_buffer_the_system_allows(range_, monkeypatch):
    environ = {"ROS_AUTOMATIC_DISCOVERY_RANGE": range_} if range_ else {}
    said, capped = configure_intake_transport(environ)
    kind, builtin, buffer, peers = _profile(environ)
    limit = receive_buffer_limit()
    assert kind == "UDPv4" and builtin == "false"  # no shared memory: the drivers' segment
    assert buffer == (INTAKE_RECEIVE_BUFFER_BYTES if limit is None else
                      min(limit, INTAKE_RECEIVE_BUFFER_BYTES))
    assert capped == (buffer < INTAKE_RECEIVE_BUFFER_BYTES)
    assert f"{buffer / 2 ** 20:.1f} MB receive buffer" in said
    if range_ == "LOCALHOST":  # rmw would add its shared memory back: the profile does its job
        assert peers == ["127.0.0.1"]
        assert environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    else:
        assert peers == [] and environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "") == range_


def test_a_capped_buffer_says_how_to_raise_it(tmp_path, monkeypatch):
    (tmp_path / "rmem_max").write_text("212992\n")  # Linux's default
    monkeypatch.setattr(transport, "RMEM_MAX", tmp_path / "rmem_max")
    environ = {}
    said, capped = configure_intake_transport(environ)
    assert capped and _profile(environ)[2] == 212992
    assert f"sudo sysctl -w net.core.rmem_max={INTAKE_RECEIVE_BUFFER_BYTES}" in said


@pytest.mark.parametrize("environ", [
    {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},  # the user's own profile
    {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
    {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},  # another middleware
    {"DENSECALIB_NODE_TRANSPORT": "middleware"},  # asked for the defaults
    {"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"},  # discovery set up by hand
    {"ROS_STATIC_PEERS": "192.168.1.7"},
    {"ROS_LOCALHOST_ONLY": "1"}])
def test_the_users_choices_are_left_alone(environ):
    before = dict(environ)
    assert configure_intake_transport(environ) is None
    assert environ == before


def test_a_profile_in_the_working_folder_is_left_alone(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert configure_intake_transport({}) is None
