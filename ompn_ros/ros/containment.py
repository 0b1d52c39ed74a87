"""DDS containment: keep Fast DDS on loopback and shared memory (ROS-free: environment and /proc only).

``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` alone is not a network boundary: rmw_fastrtps then adds
its own UDPv4 transport without an interface whitelist, whose sockets bind ``0.0.0.0`` and every
interface address, so a participant reaching the machine through a non-loopback address can talk to
a node.  The contained setup used by the tests, benchmarks, CI and ``make demo`` is

* ``FASTRTPS_DEFAULT_PROFILES_FILE`` (read by the Fast DDS 2.14 of the Jazzy wheels) and
  ``FASTDDS_DEFAULT_PROFILES_FILE`` (its newer name) = ``config/fastdds_loopback.xml``: shared
  memory plus UDPv4 whitelisted to 127.0.0.1, no built-in transports, unicast discovery to
  127.0.0.1 only;
* ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT``, so that rmw_fastrtps applies that profile
  untouched instead of adding transports;
* ``ROS_STATIC_PEERS`` empty and ``ROS_LOCALHOST_ONLY`` unset (it would override the range).

:func:`bound_sockets` lists the UDP/TCP sockets a process holds (``/proc/<pid>/fd`` matched against
``/proc/<pid>/net/{udp,udp6,tcp,tcp6}``), so a test can check that every one is bound to loopback.
Users' own launches are not affected: nothing here runs unless a caller asks for it.
"""

from __future__ import annotations

import ipaddress
import os
import random
from collections.abc import MutableMapping
from dataclasses import dataclass
from pathlib import Path

from ompn_ros.paths import config_file

PROFILE_NAME = "fastdds_loopback.xml"
PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
DISCOVERY_RANGE = "SYSTEM_DEFAULT"


def loopback_profile() -> Path:
    """The shipped Fast DDS loopback profile (``config/fastdds_loopback.xml``)."""
    return config_file(PROFILE_NAME)


def usable_domain(text: str) -> bool:
    """Whether ``text`` is a domain ID ROS 2 can use on Linux: 0..101 or 215..232 (the others map to
    ports inside the kernel's ephemeral range, where a participant may fail to bind)."""
    return text.isdigit() and (0 <= int(text) <= 101 or 215 <= int(text) <= 232)


def contain(env: MutableMapping[str, str], keep_user_domain: bool = False) -> MutableMapping[str, str]:
    """Set the contained DDS environment in ``env`` (in place; also returned).

    Keeps a ``ROS_DOMAIN_ID`` in 1..100, else picks one at random; with ``keep_user_domain`` (the
    commands a user runs: ``make demo``) any :func:`usable_domain` the user set is kept, 0 included.
    """
    profile = str(loopback_profile())
    for name in PROFILE_VARS:
        env[name] = profile
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = DISCOVERY_RANGE
    env["ROS_STATIC_PEERS"] = ""
    env.pop("ROS_LOCALHOST_ONLY", None)
    domain = env.get("ROS_DOMAIN_ID", "")
    if keep_user_domain and usable_domain(domain):
        return env
    if not domain.isdigit() or not 1 <= int(domain) <= 100:
        env["ROS_DOMAIN_ID"] = str(random.randint(1, 100))
    return env


def problems(env: MutableMapping[str, str] | None = None) -> list[str]:
    """Why ``env`` (default ``os.environ``) is not contained; empty when it is."""
    env = os.environ if env is None else env
    found = []
    profile = str(loopback_profile())
    if env.get("FASTRTPS_DEFAULT_PROFILES_FILE") != profile:
        found.append(f"FASTRTPS_DEFAULT_PROFILES_FILE is not {profile}")
    if env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != DISCOVERY_RANGE:
        found.append(f"ROS_AUTOMATIC_DISCOVERY_RANGE is not {DISCOVERY_RANGE} "
                     "(LOCALHOST makes rmw_fastrtps add an unrestricted UDP transport)")
    if env.get("ROS_STATIC_PEERS"):
        found.append("ROS_STATIC_PEERS is not empty")
    if env.get("ROS_LOCALHOST_ONLY"):
        found.append("ROS_LOCALHOST_ONLY is set")
    return found


@dataclass(frozen=True)
class BoundSocket:
    """One UDP/TCP socket of a process: protocol table, local address and port."""

    proto: str  # 'udp' | 'udp6' | 'tcp' | 'tcp6'
    address: str
    port: int

    @property
    def loopback(self) -> bool:
        addr = ipaddress.ip_address(self.address)
        if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
            addr = addr.ipv4_mapped
        return addr.is_loopback


def _decode_address(hex_addr: str) -> str:
    raw = bytes.fromhex(hex_addr)
    if len(raw) == 4:
        return str(ipaddress.IPv4Address(raw[::-1]))
    # /proc prints IPv6 as four host-order (little-endian) 32-bit words
    words = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
    return str(ipaddress.IPv6Address(words))


def bound_sockets(pid: int) -> list[BoundSocket]:
    """Every UDP/TCP socket held by process ``pid`` (Linux ``/proc``; O(sockets on the host))."""
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue  # closed meanwhile
        if target.startswith("socket:["):
            inodes.add(int(target[8:-1]))
    found = []
    for proto in ("udp", "udp6", "tcp", "tcp6"):
        table = Path(f"/proc/{pid}/net/{proto}")
        if not table.is_file():
            continue
        for line in table.read_text().splitlines()[1:]:
            cols = line.split()
            if len(cols) > 9 and int(cols[9]) in inodes:
                addr, port = cols[1].split(":")
                found.append(BoundSocket(proto, _decode_address(addr), int(port, 16)))
    return found


__all__ = ["BoundSocket", "bound_sockets", "contain", "loopback_profile", "problems"]
