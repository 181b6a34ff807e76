"""The two emulated hosts (netlab.hosts): each holds a permanent neighbour entry for its peer, so the emulated loss
falls on the traffic and never on address resolution: the kernel hands every datagram for the peer to the link at
once, and over a lossy link every datagram arrives but those the link itself dropped. Root only (namespaces, TAP
devices); CI runs as root. Nothing here depends on time: frames are counted, on the link's own counters.

Without the entries, 10 datagrams a second over a 30 % lossy link stopped arriving for seconds at a time (twice in
150 s): the kernel's unicast probes of a stale entry all got lost, and it held the datagrams while it resolved the
peer's address again (the heartbeat watchdog then rightly ended a client's control)."""
import contextlib
import json
import signal
import subprocess
import sys
import threading

import pytest
from waiting import wait_until

from netlab import Conditions, EmulatedHosts, unavailable_reason
from netlab.hosts import mac_address

reason = unavailable_reason()
pytestmark = [pytest.mark.skipif(reason is not None, reason=f"two emulated hosts: {reason}"),
              pytest.mark.integration]

PORT = 40000
DATAGRAMS = 300
LOSS = 0.3
TO_RIG = "b_to_a"  # the link's direction from the second host (workstation) to the first (rig)

RECEIVER = f"""
import socket
receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
receiver.bind(("0.0.0.0", {PORT}))
print("ready", flush=True)
while True:
    print(int.from_bytes(receiver.recv(64), "big"), flush=True)
"""
SENDER = f"""
import socket, sys
sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
for k in range({DATAGRAMS}):
    sender.sendto(k.to_bytes(4, "big"), (sys.argv[1], {PORT}))
"""


def neighbour(host, address: str) -> dict:
    entries = json.loads(subprocess.run(["ip", "-n", host.namespace, "-json", "neigh", "show", address],
                                        capture_output=True, text=True, check=True, timeout=30).stdout)
    assert len(entries) == 1, entries
    return entries[0]


def test_each_host_pins_its_peers_hardware_address():
    with EmulatedHosts(("rig", "workstation")) as lab:
        rig, workstation = lab.hosts["rig"], lab.hosts["workstation"]
        for host, peer in ((rig, workstation), (workstation, rig)):
            entry = neighbour(host, peer.address)
            assert entry["lladdr"] == mac_address(peer) and "PERMANENT" in entry["state"], entry


def send_datagrams(lab) -> None:
    """DATAGRAMS numbered datagrams from the workstation to the rig, as fast as the sender goes."""
    sender = lab.start("workstation", [sys.executable, "-c", SENDER, lab.hosts["rig"].address])
    assert sender.wait(60.0) == 0


def test_over_a_cut_link_every_datagram_still_reaches_the_link():
    """With the link cut every frame is lost, as every address-resolution probe would be: yet each datagram for
    the peer reaches the link (a kernel resolving the address would hold them back, and drop them once it gave up,
    while only its probes reached the link)."""
    with EmulatedHosts(("rig", "workstation")) as lab:
        lab.partition()
        before = lab.stats()[TO_RIG]["partitioned"]
        send_datagrams(lab)
        wait_until(lambda: lab.stats()[TO_RIG]["partitioned"] - before >= DATAGRAMS,
                   f"all {DATAGRAMS} datagrams at the cut link")


def test_over_a_30_percent_lossy_link_every_datagram_arrives_but_those_the_link_dropped():
    with EmulatedHosts(("rig", "workstation"), Conditions(delay_s=0.05, jitter_s=0.01, loss=LOSS), seed=3) as lab:
        receiver = lab.start("rig", [sys.executable, "-c", RECEIVER], stdout=subprocess.PIPE, text=True)
        assert receiver.stdout.readline().strip() == "ready"
        arrived = []
        threading.Thread(target=lambda: arrived.extend(int(line) for line in receiver.stdout), daemon=True).start()
        before = lab.stats()[TO_RIG]
        send_datagrams(lab)

        def link_done():  # every datagram reached the link and none is still in flight
            now = lab.stats()[TO_RIG]
            return now["received"] - before["received"] >= DATAGRAMS and now["in_flight"] == 0 and now
        after = wait_until(link_done, "every datagram through the link")
        dropped = after["lost"] - before["lost"]
        wait_until(lambda: len(arrived) >= DATAGRAMS - dropped,
                   f"every datagram the link did not drop at the receiver ({DATAGRAMS - dropped})")
    # Each datagram once; the link's counts may include a frame of the hosts' own (IPv6 neighbour discovery).
    assert len(set(arrived)) == len(arrived) and set(arrived) <= set(range(DATAGRAMS))
    assert 0.2 < 1 - len(arrived) / DATAGRAMS < 0.4, f"{len(arrived)} of {DATAGRAMS} arrived"  # the link did lose


# "ready" is said inside the try: a SIGINT right after it (the test sends it on reading the word) is caught too
ENDS_ON_SIGINT = """
import os, threading
try:
    print("ready", flush=True)
    threading.Event().wait()
except KeyboardInterrupt:
    os._exit(3)  # at once: no interpreter teardown
"""
IGNORES_SIGINT = """
import signal, threading
signal.signal(signal.SIGINT, signal.SIG_IGN)
print("ready", flush=True)
threading.Event().wait()
"""


# [s] A bound for the two that end on SIGINT; the one that ignores SIGINT is killed after it, so this is what the
# test costs.
STOP_TIMEOUT_S = 10.0


@contextlib.contextmanager
def sigint_ignored():
    """This process ignores SIGINT, as a background job of a script or a command under nohup does: what it starts
    inherits that, unless it is started otherwise."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def test_processes_stopped_together_end_on_sigint_and_one_that_ignores_it_is_killed():
    """Also when the lab runs in a process that ignores SIGINT: each process on the hosts starts with SIGINT at its
    default (before, all three ignored it here and were killed: [-9, -9, -9])."""
    with EmulatedHosts(("rig", "workstation")) as lab:
        with sigint_ignored():
            processes = [lab.start(host, [sys.executable, "-c", program], stdout=subprocess.PIPE, text=True)
                         for host, program in (("rig", ENDS_ON_SIGINT), ("workstation", IGNORES_SIGINT),
                                               ("workstation", ENDS_ON_SIGINT))]
        assert [process.stdout.readline().strip() for process in processes] == ["ready"] * 3
        assert lab.stop_together(processes, timeout=STOP_TIMEOUT_S) == [3, -9, 3]
