"""Which machines the stack's DDS traffic reaches: the `network` section of the stack description
(config/stack.yaml) and the launcher's options, applied as ROS 2's environment variables.

    network:
      discovery_range: subnet        # ROS_AUTOMATIC_DISCOVERY_RANGE: localhost | subnet | system_default | off
      static_peers: [192.168.50.2]   # ROS_STATIC_PEERS: the other machine(s), reached by unicast
      domain_id: 7                   # ROS_DOMAIN_ID, the same on every machine of the stack

A field left out (or null) keeps what the environment says; a discovery range that neither sets is
LOCALHOST, so by default nothing leaves this machine.
"""
from __future__ import annotations

import ipaddress
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace

DISCOVERY_RANGES = ("localhost", "subnet", "system_default", "off")
DEFAULT_DISCOVERY_RANGE = "localhost"
MAX_DOMAIN_ID = 232  # Fast DDS's port arithmetic ends here
MAX_STATIC_PEERS = 32
HOSTNAME = re.compile(r"(?=.{1,253}$)[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                      r"(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*")
RANGE_VARIABLE, PEERS_VARIABLE, DOMAIN_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_DOMAIN_ID"
VARIABLES = (RANGE_VARIABLE, PEERS_VARIABLE, DOMAIN_VARIABLE)


@dataclass(frozen=True)
class NetworkSettings:
    discovery_range: str | None = None          # one of DISCOVERY_RANGES; None: the environment's
    static_peers: tuple[str, ...] | None = None  # addresses or host names; None: the environment's
    domain_id: int | None = None                 # None: the environment's

    def over(self, base: NetworkSettings) -> NetworkSettings:
        """These settings where given, ``base``'s elsewhere (launcher options over the stack file)."""
        given = {key: value for key, value in vars(self).items() if value is not None}
        return replace(base, **given)

    def environment(self, base: Mapping[str, str]) -> dict[str, str]:
        """``base`` with the ROS 2 variables these settings give; LOCALHOST when nothing chose a range."""
        env = dict(base)
        if self.discovery_range is not None:
            env[RANGE_VARIABLE] = self.discovery_range.upper()
        elif not env.get(RANGE_VARIABLE):
            env[RANGE_VARIABLE] = DEFAULT_DISCOVERY_RANGE.upper()
        if self.static_peers is not None:
            env[PEERS_VARIABLE] = ";".join(self.static_peers)
        if self.domain_id is not None:
            env[DOMAIN_VARIABLE] = str(self.domain_id)
        return env

    def variables(self, base: Mapping[str, str]) -> dict[str, str]:
        """Only the ROS 2 variables of ``environment(base)`` (those that are set)."""
        return {name: value for name, value in self.environment(base).items() if name in VARIABLES}


def describe(env: Mapping[str, str]) -> str:
    """One line for a log: what the nodes of ``env`` will discover."""
    peers = env.get(PEERS_VARIABLE) or "none"
    return (f"DDS discovery {env.get(RANGE_VARIABLE, '?')}, static peers {peers}, "
            f"domain {env.get(DOMAIN_VARIABLE) or '0 (ROS default)'}")


def _fail(where: str, value, expectation: str):
    raise ValueError(f"{where}={value!r}: {expectation}" if where else f"{value!r}: {expectation}")


def parse_discovery_range(value, where: str = "") -> str:
    if not isinstance(value, str) or value.lower() not in DISCOVERY_RANGES:
        _fail(where, value, f"one of {', '.join(DISCOVERY_RANGES)}")
    return value.lower()


def parse_static_peers(value, where: str = "") -> tuple[str, ...]:
    if isinstance(value, str):  # "a;b" or "a,b" as on a command line or in ROS_STATIC_PEERS
        value = [peer for peer in re.split(r"[;,]", value) if peer.strip()]
    if not isinstance(value, list) or len(value) > MAX_STATIC_PEERS:
        _fail(where, value, f"a list of at most {MAX_STATIC_PEERS} addresses or host names")
    peers = []
    for peer in value:
        peer = peer.strip() if isinstance(peer, str) else peer
        if not isinstance(peer, str) or not (_is_address(peer) or HOSTNAME.fullmatch(peer)):
            _fail(where, peer, "an IP address or a host name")
        peers.append(peer)
    return tuple(peers)


def parse_domain_id(value, where: str = "") -> int:
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_DOMAIN_ID:
        _fail(where, value, f"an integer 0..{MAX_DOMAIN_ID}")
    return value


PARSERS = {"discovery_range": parse_discovery_range, "static_peers": parse_static_peers,
           "domain_id": parse_domain_id}


def parse_network(source, section) -> NetworkSettings:
    """The `network` section of a stack description (None or missing: all from the environment)."""
    if section is None:
        return NetworkSettings()
    if not isinstance(section, dict) or set(section) - set(PARSERS):
        _fail(f"{source}: network", section, f"a mapping with the keys {', '.join(PARSERS)}")
    return NetworkSettings(**{key: None if section.get(key) is None else parse(section[key], f"{source}: network.{key}")
                              for key, parse in PARSERS.items()})


def _is_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True
