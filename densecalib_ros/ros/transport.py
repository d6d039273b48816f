"""The node's own middleware settings, chosen so that camera drivers left at their defaults reach it.

Fast DDS (ROS 2 Jazzy's default middleware) passes messages between processes on one computer
through the publisher's shared-memory segment: 512 kB, shared by all the topics of the driver's
process. Images of a few hundred kB overwrite each other there before a reader takes them, so a
best-effort reader loses most frames of all but one or two cameras, and nothing on the reader's
side can enlarge the writer's segment. A reader that offers no shared-memory locator is sent the
frames over UDP instead, into its own socket, whose receive buffer it sizes itself: that is what
densecalib_node does for its participant (`configure_intake_transport`, before rclpy.init).

The user's own choice wins: a profile named by FASTRTPS_DEFAULT_PROFILES_FILE or
FASTDDS_DEFAULT_PROFILES_FILE (or the DEFAULT_FASTRTPS_PROFILES.xml Fast DDS reads from the working
folder), another RMW_IMPLEMENTATION, or DENSECALIB_NODE_TRANSPORT=middleware leave the
middleware's defaults alone.
"""
from __future__ import annotations

import atexit
import os
import tempfile
from pathlib import Path
from typing import Optional

# What a burst must fit: a frame set of 4 x 1920x1080 rgb8 is 25 MB, and a driver publishes the
# cameras of one set back to back, faster than any reader drains them.
INTAKE_RECEIVE_BUFFER_BYTES = 32 * 2 ** 20
RMEM_MAX = Path("/proc/sys/net/core/rmem_max")  # Linux caps every socket's receive buffer here
OPT_OUT = "DENSECALIB_NODE_TRANSPORT"
_PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")

_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<!-- written by densecalib_node for its own participant (densecalib_ros.ros.transport) -->
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>densecalib_udp_intake</transport_id>
      <type>UDPv4</type>
      <receiveBufferSize>{receive_bytes}</receiveBufferSize>
      <maxInitialPeersRange>32</maxInitialPeersRange>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="densecalib_node_intake" is_default_profile="true">
    <rtps>{builtin}
      <userTransports>
        <transport_id>densecalib_udp_intake</transport_id>
      </userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
</profiles>
"""
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST makes rmw_fastrtps add its own shared-memory and UDP
# transports to the participant, whatever the profile says; so the profile does what that mode
# does (no multicast, this computer as the one initial peer, 32 participants' ports tried, as
# rmw_fastrtps's) and the node's process asks rmw for the system default, which keeps the profile.
_LOCALHOST_DISCOVERY = """
      <builtin>
        <metatrafficUnicastLocatorList>
          <locator><udpv4/></locator>
        </metatrafficUnicastLocatorList>
        <initialPeersList>
          <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
        </initialPeersList>
      </builtin>"""
DISCOVERY_RANGE = "ROS_AUTOMATIC_DISCOVERY_RANGE"


def receive_buffer_limit() -> Optional[int]:
    """net.core.rmem_max in bytes, or None where it cannot be read (not Linux)."""
    try:
        return int(RMEM_MAX.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def configure_intake_transport(environ=os.environ) -> Optional[tuple[str, bool]]:
    """Give this process's Fast DDS participant a UDP-only transport with a receive buffer of
    INTAKE_RECEIVE_BUFFER_BYTES (or what the system allows), unless the user chose otherwise
    (module docstring). Call before rclpy.init. Returns what was done, for one log line, and
    whether the system caps the buffer (a warning: the line says how to raise it); None when the
    middleware keeps its own settings."""
    if environ.get(OPT_OUT, "").strip().lower() == "middleware":
        return None
    if environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        return None
    if any(environ.get(v) for v in _PROFILE_VARIABLES) or \
            Path("DEFAULT_FASTRTPS_PROFILES.xml").exists():
        return None
    discovery = environ.get(DISCOVERY_RANGE, "").strip().upper()
    if discovery not in ("", "SUBNET", "SYSTEM_DEFAULT", "LOCALHOST") or \
            environ.get("ROS_STATIC_PEERS") or environ.get("ROS_LOCALHOST_ONLY") == "1":
        return None  # discovery set up by hand: not ours to rebuild
    limit = receive_buffer_limit()
    receive = INTAKE_RECEIVE_BUFFER_BYTES if limit is None else min(
        INTAKE_RECEIVE_BUFFER_BYTES, limit)
    fd, path = tempfile.mkstemp(prefix="densecalib_node_fastdds.", suffix=".xml")
    with os.fdopen(fd, "w") as f:
        f.write(_PROFILE.format(receive_bytes=receive, builtin=_LOCALHOST_DISCOVERY
                                if discovery == "LOCALHOST" else ""))
    atexit.register(lambda: Path(path).unlink(missing_ok=True))
    environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = path
    if discovery == "LOCALHOST":
        environ[DISCOVERY_RANGE] = "SYSTEM_DEFAULT"
    said = (f"image intake: this node's Fast DDS participant receives over UDP with a "
            f"{receive / 2 ** 20:.1f} MB receive buffer (a driver's shared-memory segment drops "
            f"large images); {OPT_OUT}=middleware, or a profile of your own in "
            f"FASTRTPS_DEFAULT_PROFILES_FILE, keeps the middleware's settings")
    capped = receive < INTAKE_RECEIVE_BUFFER_BYTES
    if capped:
        said += (f"; net.core.rmem_max caps the buffer at {receive / 2 ** 20:.1f} MB, which "
                 "loses frames of large images: raise it (sudo sysctl -w "
                 f"net.core.rmem_max={INTAKE_RECEIVE_BUFFER_BYTES})")
    return said, capped
