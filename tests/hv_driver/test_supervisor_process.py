"""The HV supervisor in a process of its own (`sim_fallback.supervised`: a simulated rig behind `hv_driver.server`)
and its client `RemoteSupply`: a node that dies or falls silent leaves no output energised (NODE_LOST), a lost
supervisor is reported (SUPERVISOR_LOST) and refuses every call, a second node cannot take a supervisor over that
its node still holds. Waits are for events, with generous deadlines; nothing here asserts a duration."""
import dataclasses
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import pytest
from waiting import GENEROUS_S, wait_until

from hv_driver import ChannelConfig, ControlError, Fault, FaultLatchedError, HvError, RemoteSupply, SupervisorLostError

pytestmark = pytest.mark.integration

SUPERVISED = [sys.executable, "-m", "sim_fallback.supervised"]
CHANNELS = [ChannelConfig("front", 0, slew_rate_v_per_s=8000.0), ChannelConfig("back", 1, slew_rate_v_per_s=8000.0)]
# The windows a test does not test are longer than any stall of a loaded host: a late keep-alive, heartbeat or
# reply must not decide its outcome.
LONG_S = 30.0
KEEPALIVE_UNDER_TEST_S = 5.0

# A node stand-in in a process of its own: takes control, ramps front to 2400 V, says "up", then beats on (its
# client stays alive) until it is killed.
NODE = f"""
import json, sys, time
from hv_driver import RemoteSupply
supply = RemoteSupply(json.loads(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]).open()
token = supply.claim_control("sequencer")
supply.enable("front")
handle = supply.ramp_to("front", 2400.0, token=token)
assert handle.wait({GENEROUS_S!r}) and handle.succeeded, handle.message
print("up", flush=True)
while True:
    supply.heartbeat(token)
    time.sleep(0.1)
"""


def spec(**overrides) -> dict:
    return {"ports": [], "baudrate": None, "channels": [dataclasses.asdict(c) for c in CHANNELS],
            "dialect": "iseg-edcp", "loop_rate_hz": 100.0, "link_timeout_s": LONG_S, "heartbeat_timeout_s": LONG_S,
            "expected_identity": "", "realtime_priority": 10, "orphan_timeout_s": 60.0, "keepalive_timeout_s": LONG_S,
            "simulated": {"channels": 4, "devices": 1}, **overrides}


@pytest.fixture
def socket_path():
    directory = tempfile.mkdtemp(prefix="hv-")  # short: a Unix socket path has at most 107 bytes
    yield os.path.join(directory, "s.sock")
    shutil.rmtree(directory, ignore_errors=True)


def front(supply):
    return supply.snapshot().channel("front")


def test_a_killed_node_leaves_no_output_energised_and_nothing_comes_back_by_itself(socket_path):
    node = subprocess.Popen([sys.executable, "-c", NODE, json.dumps(SUPERVISED), json.dumps(spec()), socket_path],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert node.stdout.readline().strip() == "up"
        os.kill(node.pid, signal.SIGKILL)  # its client (the beating thread) dies with it
        node.wait()
        with pytest.raises(HvError, match="other settings"):  # only a node of the same settings takes it over
            RemoteSupply(SUPERVISED, spec(loop_rate_hz=50.0), socket_path).open()
        supply = RemoteSupply(SUPERVISED, spec(), socket_path).open()
    finally:
        node.kill()
    try:
        wait_until(lambda: front(supply).measured_voltage < 50.0 and not front(supply).output_enabled,
                   "output below 50 V and off after the node's death")
        lost = front(supply)
        assert Fault.NODE_LOST in lost.faults and "channel to the supervisor closed" in lost.fault_text
        assert Fault.NODE_LOST in supply.snapshot().channel("back").faults  # every channel latches it
        assert supply.snapshot().controller == ""  # the dead node's client lost control
        # what happened while no node drained the supervisor's events waits for the next one (a restarted node)
        drained = [(event.level, event.text[:60]) for event in supply.drain_events()]
        assert (logging.WARNING, "HV driver node lost: its channel to the supervisor closed (t") in drained
        for name in ("front", "back"):
            assert (logging.ERROR, f"channel {name!r}: fault latched: node_lost: HV driver node lost: "[:60]) in drained
        token = supply.claim_control("operator")
        with pytest.raises(FaultLatchedError):  # latched until reset on purpose
            supply.enable("front")
        assert supply.reset_faults() == ["front", "back"]
        supply.enable("front")
        assert front(supply).measured_voltage < 50.0  # a reset switches nothing back on
        assert supply.ramp_to("front", 600.0, token=token).wait(GENEROUS_S)
    finally:
        supply.close()


def test_a_node_whose_keep_alive_stops_is_lost_and_its_outputs_ramp_down(socket_path):
    """The lapse is waited for, however late it comes; its keep-alive timeout is longer than the stalls of a loaded
    host, so that one before the injected stop does not lapse it first (the NODE_LOST rule itself is tested on the
    supervisor's clock: test_node_lost.py)."""
    supply = RemoteSupply(SUPERVISED, spec(keepalive_timeout_s=KEEPALIVE_UNDER_TEST_S), socket_path).open()
    try:
        token = supply.claim_control("sequencer")
        supply.enable("front")
        assert supply.ramp_to("front", 1500.0, token=token).wait(GENEROUS_S)
        supply._stop.set()  # fault injection: the keep-alive thread stops, the channel stays open
        supply._beater.join()
        wait_until(lambda: Fault.NODE_LOST in front(supply).faults, "NODE_LOST after the keep-alive stopped")
        assert f"no keep-alive for more than {KEEPALIVE_UNDER_TEST_S:g} s" in front(supply).fault_text
        wait_until(lambda: front(supply).measured_voltage < 50.0, "the output ramped down")
        with pytest.raises(ControlError):  # the session ended with the node
            supply.heartbeat(token)
        refused = []
        supply.forward_heartbeat(token, refused.append)  # as the node forwards its client's: refused by reply
        wait_until(lambda: refused, "the forwarded heartbeat's refusal")
        assert isinstance(refused[0], ControlError) and "no client holds control" in str(refused[0])
    finally:
        supply.close()


def test_a_supervisor_stalled_past_both_timeouts_keeps_its_node_and_the_client_whose_beats_were_forwarded(
        socket_path):
    """The supervisor process is stopped for 6 s, past its keep-alive and heartbeat timeouts, while the node lives
    on: it beats its keep-alive and forwards its client's heartbeats (without waiting for answers). They wait in the
    channel and are read, with their sending stamps, before any silence is judged. (The timeouts are the stall's
    subject: shorter than it, yet longer than this test's own process could stall on a loaded host.)"""
    supply = RemoteSupply(SUPERVISED, spec(keepalive_timeout_s=3.0, heartbeat_timeout_s=4.0), socket_path).open()
    refused, stop = [], threading.Event()

    def client(token: str):
        while not stop.wait(0.1):
            supply.forward_heartbeat(token, refused.append)
    beating = None
    try:
        token = supply.claim_control("sequencer")
        supply.enable("front")
        assert supply.ramp_to("front", 1000.0, token=token).wait(GENEROUS_S)
        beating = threading.Thread(target=client, args=(token,))
        beating.start()
        os.kill(supply.pid, signal.SIGSTOP)
        try:
            time.sleep(6.0)  # the stall itself, not a wait for an event
        finally:
            os.kill(supply.pid, signal.SIGCONT)
        assert supply.wait_cycles(10, GENEROUS_S)
        snapshot = supply.snapshot()
        assert not any(c.faults for c in snapshot.channels), snapshot.channel("front").fault_text
        assert snapshot.controller == "sequencer" and snapshot.channel("front").output_enabled and not refused
    finally:
        stop.set()
        if beating is not None:
            beating.join()
        supply.close()


def test_a_lost_supervisor_is_reported_on_every_channel_and_refuses_every_call(socket_path):
    reasons = []
    supply = RemoteSupply(SUPERVISED, spec(), socket_path, on_lost=reasons.append).open()
    assert front(supply).faults == Fault(0)
    os.kill(supply.pid, signal.SIGKILL)
    # the loss is noted (``lost``) a moment before on_lost is called: wait for the call, the later event
    wait_until(lambda: reasons, "the supervisor's loss reported")
    assert supply.lost is not None
    snapshot = supply.snapshot()
    assert all(Fault.SUPERVISOR_LOST in c.faults for c in snapshot.channels)
    assert "only the supplies' own means still hold" in snapshot.channel("front").fault_text
    with pytest.raises(SupervisorLostError, match="supervisor process lost"):
        supply.claim_control("sequencer")
    with pytest.raises(SupervisorLostError):
        supply.ramp_to("front", 100.0, token="x")
    with pytest.raises(SupervisorLostError, match="supervisor_lost"):
        supply.forward_heartbeat("x", reasons.append)
    assert len(reasons) == 1
    supply.close()  # nothing left to close: no error, no wait


def test_a_second_node_cannot_take_over_a_supervisor_its_node_still_holds(socket_path):
    supply = RemoteSupply(SUPERVISED, spec(), socket_path).open()
    try:
        with pytest.raises(HvError, match="does not answer"):
            RemoteSupply(SUPERVISED, spec(), socket_path).open()
        supply.enable("front")  # the first node is still served
    finally:
        supply.close()


def test_a_supply_that_cannot_be_opened_is_refused_with_the_supervisors_reason(socket_path):
    bad = spec(channels=[dataclasses.asdict(ChannelConfig("front", 7))])
    with pytest.raises(HvError, match="index 7 is not on the supply"):
        RemoteSupply(SUPERVISED, bad, socket_path).open()


def test_an_unknown_simulated_link_is_refused_naming_the_choices(socket_path):
    bad = spec(simulated={"channels": 4, "devices": 1, "link": "usb"})
    with pytest.raises(HvError, match="link='usb': one of memory, pty"):
        RemoteSupply(SUPERVISED, bad, socket_path).open()


def children(pid: int) -> list[int]:
    with open(f"/proc/{pid}/task/{pid}/children") as listing:
        return [int(child) for child in listing.read().split()]


def test_a_host_that_deschedules_the_simulation_trips_no_link_fault(socket_path):
    """A loaded host, or a hypervisor taking a virtual CPU away, can stop a simulation apart from the driver, and
    then the driver too. The simulated supplies answer within the driver's own exchange, so neither stall makes
    them late: nothing latches at the product's link timeout (a simulation in a process of its own, stopped for
    longer than that timeout, made the driver latch LINK)."""
    supply = RemoteSupply(SUPERVISED, spec(link_timeout_s=0.5), socket_path).open()
    try:
        token = supply.claim_control("sequencer")
        supply.enable("front")
        assert supply.ramp_to("front", 2400.0, token=token).wait(GENEROUS_S)
        stalled = children(supply.pid)  # what simulates the supplies, if it runs apart from the driver
        for pid in stalled:
            os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(1.0)  # the stall itself: the simulation alone
            os.kill(supply.pid, signal.SIGSTOP)
            time.sleep(1.0)  # then the driver too
        finally:
            for pid in [supply.pid, *stalled]:
                os.kill(pid, signal.SIGCONT)
        assert supply.wait_cycles(10, GENEROUS_S)
        channel = front(supply)
        assert not channel.faults, channel.fault_text
        assert channel.output_enabled and channel.measured_voltage > 2300.0
    finally:
        supply.close()
