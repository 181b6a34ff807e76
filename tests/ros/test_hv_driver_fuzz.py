"""Fuzz of every input of the hv_driver node: ramp goals, inject_fault, estop, reset_faults, claim and release
of control, assembly/safe_voltage and hv/heartbeat, as random sequences of messages built by hypothesis
strategies for the message types (absurd numbers, arbitrary text, signatures: live, replayed and forged).

After every input the node answers and keeps publishing hv/state, no setpoint is above its ceiling, no
output above the hard maximum, latched faults stay latched until a reset, an e-stop latches on every
channel, and a ramp goal is obeyed only when signed afresh for the live control session."""
import math
import threading

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from ros_testing import Inbox, call, wait_for
from waiting import GENEROUS_S
from softblock_interfaces.action import RampChannel
from softblock_interfaces.msg import HvHeartbeat, HvState
from softblock_interfaces.srv import ClaimControl, InjectFault, ReleaseControl
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from hv_driver.control import HEARTBEAT, RELEASE, SessionKey, ramp_command
from sim_fallback.hv_supply import FAULTS
from softblock_ros.client import ActionClient
from softblock_ros.hv_driver_node import HvDriverNode
from softblock_ros.qos import LATCHED

pytestmark = pytest.mark.integration

MAX_VOLTAGE = 3000.0
TOLERANCE = 100.0  # [V] readback tolerance: the measured voltage may lag a falling ceiling by this much
LIVE, REPLAYED = object(), object()  # strategy markers: sign afresh for the live session; re-send its last signature

text = st.text(st.characters(exclude_categories=("Cs",)), max_size=80)  # anything a ROS string can carry
names = st.one_of(st.sampled_from(["front", "back", ""]), text)
numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(min_value=-10.0, max_value=3500.0),
                    st.sampled_from([0.0, -0.0, 1e-9, 1e-300, 2400.0, 3000.0, 3000.0000001, 1e308]))
signatures = st.one_of(st.just(LIVE), st.just(REPLAYED),
                       st.tuples(text, st.integers(0, 2**64 - 1), st.one_of(text, st.just("0" * 64))))
# "disconnect" closes the simulated device for good; its handling is tested in tests/hv_driver.
# Injected faults after which the simulated supply still answers every query (any other may leave the link failing).
SUPPLY_KEEPS_ANSWERING = ("over_current", "readback_drift", "load_change")
faults = st.one_of(st.sampled_from([f for f in FAULTS if f != "disconnect"] + ["clear"]), text)
ramp_goals = st.tuples(names, numbers, numbers, signatures)


class Fuzz:
    """The node under test and one client handle per input."""

    def __init__(self, ros_context, spin):
        # A short heartbeat timeout on purpose: a session lapsing between two inputs is one of the states the fuzz
        # explores, and every check holds whether or not it did (a lapsed session refuses even a fresh signature).
        # hv/state at its highest rate: each step and check waits for the next one.
        self.driver = HvDriverNode(context=ros_context, parameter_overrides=[
            Parameter("slew_rate_v_per_s", value=8000.0), Parameter("link_timeout_s", value=1.0),
            Parameter("heartbeat_timeout_s", value=1.0), Parameter("publish_rate_hz", value=200.0)])
        self.node = n = rclpy.create_node("hv_fuzz_client", context=ros_context)
        self.ramp = ActionClient(n, RampChannel, "hv/ramp")
        self.services = {name: n.create_client(kind, f"hv/{name}") for name, kind in (
            ("estop", Trigger), ("reset_faults", Trigger), ("inject_fault", InjectFault),
            ("claim_control", ClaimControl), ("release_control", ReleaseControl))}
        self.heartbeat = n.create_publisher(HvHeartbeat, "hv/heartbeat", 10)
        self.safe_voltage = n.create_publisher(Float64, "assembly/safe_voltage", LATCHED)
        self.state = Inbox(n, HvState, "hv/state")
        self.diagnostics = Inbox(n, DiagnosticArray, "/diagnostics")
        self.link_may_fail = False  # a fault was injected since the last wait for the link to answer
        spin(self.driver, n)
        assert self.driver.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert self.driver.trigger_activate() == TransitionCallbackReturn.SUCCESS
        assert self.ramp.wait_for_server(timeout_sec=GENEROUS_S)


@pytest.fixture(scope="module")
def fuzz(ros_context, spin):
    return Fuzz(ros_context, spin)


def link_answers(array: DiagnosticArray) -> bool:
    """The driver's last exchange with the supply succeeded (no link error on any channel's status)."""
    return all(kv.value == "" for status in array.status for kv in status.values if kv.key == "link_error")


class DriverInputs(RuleBasedStateMachine):
    fuzz: Fuzz  # set by the test

    @initialize()
    def clean_state(self):
        """No session, no injected fault, no latched fault, outputs on at 0 V, no assembly ceiling."""
        f = self.fuzz
        self.key = None       # the live control session's key, as far as this client knows
        self.last = ("", 0, "")  # the last signature sent for the live session
        self.goals = []       # (signed afresh for the live session when sent, result future)
        self.lock = threading.Lock()
        call(f.services["inject_fault"], InjectFault.Request(fault="clear"))
        # A reset before the supply answers again after an injected link fault latches LINK again at once (still
        # no valid reply for longer than link_timeout_s: the cause is present), so after one wait for a valid reply
        # first (diagnostics from after the clear: they come at 1 Hz).
        if f.link_may_fail:
            f.diagnostics.messages.clear()
            f.diagnostics.wait(link_answers)
            f.link_may_fail = False
        f.safe_voltage.publish(Float64(data=5000.0))
        assert call(f.services["estop"], Trigger.Request()).success
        wait_for(lambda: self._state(lambda s: s.estop), what="the e-stop")
        assert call(f.services["reset_faults"], Trigger.Request()).success
        self.settled = self._state(lambda s: not s.estop and all(not c.faults for c in s.channels))

    def _state(self, predicate=lambda s: True) -> HvState:
        """The next hv/state (from now on) that satisfies ``predicate``: the node is alive and publishing."""
        self.fuzz.state.messages.clear()
        return self.fuzz.state.wait(predicate)

    def _signed(self, signature, command) -> tuple[dict, bool]:
        """The message fields of ``signature`` for ``command``, and whether they are a fresh live signature."""
        fresh = signature is LIVE and self.key is not None
        if fresh:
            self.last = self.key.sign(command)
        fields = self.last if signature is LIVE or signature is REPLAYED else signature
        return dict(zip(("session", "counter", "mac"), fields)), fresh

    @rule(goal=ramp_goals)
    def ramp(self, goal):
        channel, target, slew, signature = goal
        fields, fresh = self._signed(signature, ramp_command(channel, target, slew))
        sent = self.fuzz.ramp.send_goal_async(RampChannel.Goal(channel=channel, target=target, slew_rate=slew,
                                                                **fields))
        handle = wait_for(sent.done, what="the goal response") and sent.result()
        assert handle.accepted  # refusals come back as aborted results naming the reason
        self.goals.append((fresh, handle.get_result_async()))

    @rule(fault=faults, channel=names)
    def inject_fault(self, fault, channel):
        self.fuzz.link_may_fail |= fault not in (*SUPPLY_KEEPS_ANSWERING, "clear")
        reply = call(self.fuzz.services["inject_fault"], InjectFault.Request(channel=channel, fault=fault))
        if fault not in FAULTS and fault != "clear":  # refused, naming the choices of what was wrong
            assert not reply.success and ("over_current, no_reply" in reply.message
                                          or "unknown, configured are ['back', 'front']" in reply.message)

    @rule()
    def estop(self):
        assert call(self.fuzz.services["estop"], Trigger.Request()).success
        self.key = None
        # Shown off once the device confirmed the cut; over a failing link (an injected no_reply or deaf) it stays
        # shown on until LINK names why.
        state = self._state(lambda s: s.estop and all(not c.output_enabled or c.faults & c.FAULT_LINK
                                                      for c in s.channels))
        assert all(c.faults & c.FAULT_ESTOP and c.setpoint == 0.0 for c in state.channels)

    @rule()
    def reset_faults(self):
        assert call(self.fuzz.services["reset_faults"], Trigger.Request()).message.startswith("faults cleared")
        self.settled = None  # faults may clear now

    @rule(client=names, nonce=text)
    def claim(self, client, nonce):
        reply = call(self.fuzz.services["claim_control"], ClaimControl.Request(client=client, nonce=nonce))
        if reply.success:
            assert len(reply.token) == 32 and reply.heartbeat_timeout == 1.0
            self.key = SessionKey(reply.token)
            assert reply.session == self.key.session
        else:
            assert reply.token == reply.session == "" and reply.message

    @rule(signature=signatures)
    def release(self, signature):
        fields, fresh = self._signed(signature, RELEASE)
        reply = call(self.fuzz.services["release_control"], ReleaseControl.Request(**fields))
        if reply.success:
            assert fresh
            self.key = None
        else:
            assert reply.message.startswith("refused:")  # a fresh one too, once the session lapsed

    @rule(signature=signatures)
    def heartbeat(self, signature):
        self.fuzz.heartbeat.publish(HvHeartbeat(**self._signed(signature, HEARTBEAT)[0]))

    @rule(voltage=numbers)
    def safe_voltage(self, voltage):
        self.fuzz.safe_voltage.publish(Float64(data=voltage))

    @invariant()
    def alive_and_safe(self):
        if not hasattr(self, "goals"):
            return
        state = self._state()
        for channel in state.channels:
            assert 0.0 <= channel.setpoint <= channel.ceiling <= MAX_VOLTAGE, channel
            assert channel.measured_voltage <= MAX_VOLTAGE + TOLERANCE, channel
        if self.settled is not None:  # latched: no fault bit clears without a reset
            for before, now in zip(self.settled.channels, state.channels):
                assert now.faults & before.faults == before.faults, (before.fault_text, now.fault_text)
        self.settled = state

    def teardown(self):
        """Every goal ended; those not signed afresh for the live session were refused, naming the control holder."""
        if not hasattr(self, "goals"):
            return
        call(self.fuzz.services["estop"], Trigger.Request())  # ends every ramp still running
        for fresh, future in self.goals:
            wait_for(future.done, what="a ramp goal's result")
            result = future.result().result
            if not fresh:
                assert not result.success and result.message.startswith(
                    ("refused:", "target=", "slew_rate=", "channel=")), result.message


def test_every_input_of_the_hv_driver_node(fuzz):
    DriverInputs.fuzz = fuzz
    machine = DriverInputs.TestCase
    machine.settings = settings(max_examples=25, stateful_step_count=12, deadline=None,
                                suppress_health_check=list(HealthCheck))
    machine("runTest").runTest()


def test_a_fuzzed_ceiling_never_raises_the_setpoint(fuzz):
    """A NaN, infinite or negative safe voltage sets the ceiling to 0 V rather than lifting it."""
    for voltage in (math.nan, math.inf, -math.inf, -1.0):
        fuzz.safe_voltage.publish(Float64(data=voltage))
        fuzz.state.messages.clear()
        fuzz.state.wait(lambda s: all(c.ceiling == 0.0 and c.setpoint == 0.0 for c in s.channels))
    fuzz.safe_voltage.publish(Float64(data=5000.0))
