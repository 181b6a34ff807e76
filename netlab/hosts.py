"""Two emulated hosts: a network namespace each, joined through a TAP device per namespace whose frames a
`netlab.link.Link` carries. Linux, root, /dev/net/tun.

Each namespace gets its loopback, its TAP device with one address of a private /24 and a multicast route
(DDS discovers its peers by multicast), a permanent neighbour entry for its peer, and nothing else: no route
out of the pair, so nothing sent inside reaches any other network. The neighbour entries keep the emulated
loss on the traffic itself: address resolution over a very lossy link fails now and then (three lost unicast
probes, 13 % of the time at 30 % loss), and the kernel then holds every datagram to the peer for seconds
while it resolves the address again; a lab pins its rig PC's address the same way. A TAP file descriptor keeps working after its device moves into a namespace;
the device disappears when the descriptor closes. Names carry the owner's pid, so leftovers of a killed
run are recognised (and removed by ``remove_leftovers``) while another live run is left alone.
"""
from __future__ import annotations

import fcntl
import ipaddress
import json
import os
import re
import signal
import struct
import subprocess
from dataclasses import dataclass
from pathlib import Path

TUN_DEVICE = Path("/dev/net/tun")
TUNSETIFF = 0x400454CA  # linux/if_tun.h
IFF_TAP, IFF_NO_PI = 0x0002, 0x1000
PREFIX = "sbnet"  # namespaces sbnet<pid>-<host>, devices sbnet<pid><letter>
DEFAULT_SUBNET = "10.213.0.0/24"
HOST_NAME = re.compile(r"[a-z][a-z0-9]{0,15}")
MULTICAST = "224.0.0.0/4"


class HostsError(RuntimeError):
    """The emulated hosts cannot be set up here (not root, no TUN device, a command failed)."""


@dataclass(frozen=True)
class Host:
    name: str        # e.g. "rig"
    namespace: str   # e.g. "sbnet4711-rig": ip netns exec <namespace> <command>
    device: str      # its TAP device, e.g. "sbnet4711a"
    address: str     # e.g. "10.213.0.1"

    def command(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this host's namespace."""
        return ["ip", "netns", "exec", self.namespace, *argv]


def unavailable_reason() -> str | None:
    """Why the hosts cannot be created here, or None."""
    if os.geteuid() != 0:
        return "needs root (network namespaces and TAP devices)"
    if not TUN_DEVICE.exists():
        return f"needs {TUN_DEVICE} (TAP devices)"
    try:
        subprocess.run(["ip", "netns", "list"], check=True, capture_output=True, timeout=10)
    except (OSError, subprocess.SubprocessError) as error:
        return f"needs the ip command with netns support ({error})"
    return None


def _ip(*args: str) -> str:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)
    if result.returncode != 0:
        raise HostsError(f"ip {' '.join(args)}: {result.stderr.strip()}")
    return result.stdout


def mac_address(host: Host) -> str:
    """The hardware address of ``host``'s TAP device, e.g. "2e:41:07:9a:c3:10"."""
    return json.loads(_ip("-n", host.namespace, "-json", "link", "show", "dev", host.device))[0]["address"]


def _open_tap(name: str) -> int:
    fd = os.open(TUN_DEVICE, os.O_RDWR | os.O_NONBLOCK)
    try:
        fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TAP | IFF_NO_PI))
    except OSError:
        os.close(fd)
        raise
    return fd


def _namespaces() -> list[str]:
    return [line.split()[0] for line in _ip("netns", "list").splitlines() if line.strip()]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def kill_processes(namespace: str) -> None:
    """SIGKILL every process still running inside ``namespace``."""
    result = subprocess.run(["ip", "netns", "pids", namespace], capture_output=True, text=True, timeout=30)
    for pid in (int(word) for word in result.stdout.split() if word.isdigit()):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def remove_namespace(namespace: str) -> None:
    kill_processes(namespace)
    subprocess.run(["ip", "netns", "delete", namespace], capture_output=True, timeout=30)


def remove_leftovers() -> list[str]:
    """Remove the namespaces (and what runs in them) of earlier runs whose owner process is gone."""
    removed = []
    for namespace in _namespaces():
        match = re.fullmatch(rf"{PREFIX}(\d+)-[a-z0-9]+", namespace)
        if match and int(match.group(1)) != os.getpid() and not _alive(int(match.group(1))):
            remove_namespace(namespace)
            removed.append(namespace)
    return removed


def create_hosts(names: tuple[str, str], subnet: str = DEFAULT_SUBNET) -> tuple[tuple[Host, Host], tuple[int, int]]:
    """Two namespaces on ``subnet`` (.1 for the first, .2 for the second); returns the hosts and the TAP
    descriptors that carry their frames (hand them to a `Link`). Whatever was created is removed again if
    a step fails."""
    reason = unavailable_reason()
    if reason:
        raise HostsError(reason)
    if len(names) != 2 or len(set(names)) != 2 or not all(HOST_NAME.fullmatch(name) for name in names):
        raise ValueError(f"hosts={names!r}: two different names of lower-case letters and digits")
    network = ipaddress.ip_network(subnet)
    if network.version != 4 or network.prefixlen != 24 or not network.is_private:
        raise ValueError(f"subnet={subnet!r}: a private IPv4 /24, e.g. {DEFAULT_SUBNET}")
    pid = os.getpid()
    hosts = tuple(Host(name, f"{PREFIX}{pid}-{name}", f"{PREFIX}{pid}{letter}", str(network[index + 1]))
                  for index, (name, letter) in enumerate(zip(names, "ab")))
    fds: list[int] = []
    try:
        for host in hosts:
            _ip("netns", "add", host.namespace)
            fds.append(_open_tap(host.device))
            _ip("link", "set", host.device, "netns", host.namespace)
            inside = ("-n", host.namespace)
            _ip(*inside, "link", "set", "lo", "up")
            _ip(*inside, "address", "add", f"{host.address}/{network.prefixlen}", "dev", host.device)
            _ip(*inside, "link", "set", host.device, "up")
            _ip(*inside, "route", "add", MULTICAST, "dev", host.device)
        for host, peer in ((hosts[0], hosts[1]), (hosts[1], hosts[0])):
            _ip("-n", host.namespace, "neigh", "replace", peer.address, "lladdr", mac_address(peer), "nud", "permanent",
                "dev", host.device)
    except BaseException:
        for fd in fds:
            os.close(fd)
        remove_hosts(hosts)
        raise
    return hosts, (fds[0], fds[1])


def remove_hosts(hosts) -> None:
    """Kill what still runs in the hosts' namespaces and delete them (devices go with their descriptors)."""
    present = set(_namespaces())
    for host in hosts:
        if host.namespace in present:
            remove_namespace(host.namespace)
