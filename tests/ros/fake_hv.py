"""A small stand-in for the HV driver node: `hv/ramp`, `hv/pulse` (square trains on the fake outputs),
`hv/state` (50 Hz), `hv/estop`, `hv/heartbeat`,
`hv/claim_control` / `hv/release_control` (one session at a time, checked by the driver's own `ControlClaim`:
heartbeats, ramps and pulses must be signed for the live session).

Ramps move the measured voltage linearly over the minimum-jerk duration (1.875 |dV| / slew_rate).
Faults are injected deterministically: ``fault_during_ramp = (ramp_channel, target, fault_channel)``
latches OVER_CURRENT on ``fault_channel`` half-way through the first matching ramp; like the real
driver, a latched fault cuts that output at once and refuses further ramps on it.
"""
import math
import threading
import time

from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.node import Node
from softblock_interfaces.action import PulseChannels, RampChannel
from softblock_interfaces.msg import HvChannelState, HvHeartbeat, HvState
from softblock_interfaces.srv import ClaimControl, ReleaseControl
from std_srvs.srv import Trigger

from hv_driver.control import ControlClaim, ControlError, pulse_command, ramp_command, session_id, signed

DEFAULT_SLEW_RATE = 100_000.0  # [V/s]
STEP = 0.005  # [s]


class FakeHv(Node):
    def __init__(self, channels, **kwargs):
        super().__init__("fake_hv", **kwargs)
        self.channels = {name: HvChannelState(name=name, index=index) for index, name in enumerate(channels)}
        self.lock = threading.Lock()
        self.estop = False
        self.heartbeats = 0
        self.control = ControlClaim(math.inf)
        self.ramps: list[tuple[str, float]] = []
        self.pulses: list[tuple[tuple[str, ...], int]] = []  # (channels, cycles) of each train run
        self.fault_during_ramp: tuple[str, float, str] | None = None
        self.silent = False  # hv/state stops (a driver lost to its clients) while its services keep answering
        group = ReentrantCallbackGroup()
        self.state_pub = self.create_publisher(HvState, "hv/state", 10)
        self.create_timer(0.02, self.publish_state, callback_group=group)
        self.create_subscription(HvHeartbeat, "hv/heartbeat", self.on_heartbeat, 10, callback_group=group)
        self.create_service(Trigger, "hv/estop", self.on_estop, callback_group=group)
        self.create_service(ClaimControl, "hv/claim_control", self.on_claim, callback_group=group)
        self.create_service(ReleaseControl, "hv/release_control", self.on_release, callback_group=group)
        self.active = True  # the driver's lifecycle: inactive = every output off, ramps refused
        self.create_service(GetState, "hv_driver/get_state", self.on_get_state, callback_group=group)
        self.create_service(ChangeState, "hv_driver/change_state", self.on_change_state, callback_group=group)
        self.server = ActionServer(self, RampChannel, "hv/ramp", execute_callback=self.execute,
                                   cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group)
        self.pulse_server = ActionServer(self, PulseChannels, "hv/pulse", execute_callback=self.execute_pulse,
                                         cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group)

    def reset(self) -> None:
        with self.lock:
            self.estop, self.ramps, self.fault_during_ramp = False, [], None
            self.control = ControlClaim(math.inf)
            self.pulses = []
            self.silent = False
            self.active = True
            for channel in self.channels.values():
                channel.faults, channel.fault_text, channel.measured_voltage = 0, "", 0.0
                channel.setpoint = channel.target = 0.0
                channel.output_enabled = channel.ramping = False

    def obeyed(self, message, command) -> bool:
        """Whether ``message`` (a heartbeat, goal or release request) is signed for the live session."""
        with self.lock:
            try:
                self.control.confirm(signed(message.session, message.counter, message.mac), time.monotonic(),
                                     command)
                return True
            except ControlError:
                return False

    def on_heartbeat(self, msg: HvHeartbeat) -> None:
        if self.obeyed(msg, ("heartbeat",)):
            self.heartbeats += 1

    def on_claim(self, request, response):
        with self.lock:
            try:
                response.token = self.control.claim(request.client, time.monotonic(), request.nonce)
            except ControlError as error:
                response.success, response.message = False, str(error)
                return response
        response.success, response.session, response.heartbeat_timeout = True, session_id(response.token), 2.0
        return response

    def on_release(self, request, response):
        with self.lock:
            try:
                self.control.release(signed(request.session, request.counter, request.mac), time.monotonic())
                response.success = True
            except ControlError as error:
                response.success, response.message = False, str(error)
        return response

    def on_get_state(self, _request, response):
        response.current_state = (State(id=State.PRIMARY_STATE_ACTIVE, label="active") if self.active else
                                  State(id=State.PRIMARY_STATE_INACTIVE, label="inactive"))
        return response

    def on_change_state(self, request, response):
        activate = request.transition.id == Transition.TRANSITION_ACTIVATE
        with self.lock:
            if activate == self.active or request.transition.id not in (Transition.TRANSITION_ACTIVATE,
                                                                        Transition.TRANSITION_DEACTIVATE):
                response.success = False
                return response
            self.active = activate
            for channel in self.channels.values():  # as the driver: on at 0 V when active, off when inactive
                channel.measured_voltage = channel.setpoint = 0.0
                channel.output_enabled = activate and not channel.faults
        response.success = True
        return response

    def publish_state(self) -> None:
        with self.lock:
            if self.silent:
                return
            msg = HvState(device_id="fake", backend="sim", estop=self.estop, channels=list(self.channels.values()))
            msg.header.stamp = self.get_clock().now().to_msg()
            self.state_pub.publish(msg)

    def latch(self, name: str, bit: int, text: str) -> None:
        with self.lock:
            channel = self.channels[name]
            channel.faults |= bit
            channel.fault_text = text
            channel.measured_voltage = channel.setpoint = 0.0
            channel.output_enabled = channel.ramping = False

    def on_estop(self, _request, response):
        for name in self.channels:
            self.latch(name, HvChannelState.FAULT_ESTOP, "ESTOP")
        self.estop = True
        with self.lock:
            self.control.end("control ended by an emergency stop")  # as the driver
        response.success, response.message = True, "e-stop latched"
        return response

    def set_voltage(self, channel: HvChannelState, voltage: float) -> None:
        with self.lock:
            channel.measured_voltage = channel.setpoint = voltage
            channel.output_enabled = voltage > 0.0 or channel.output_enabled

    def execute(self, goal_handle):
        goal = goal_handle.request
        channel = self.channels.get(goal.channel)
        if channel is None or channel.faults or not self.active or not self.obeyed(
                goal, ramp_command(goal.channel, goal.target, goal.slew_rate)):
            goal_handle.abort()
            reason = ("unknown channel" if channel is None else "faults latched" if channel.faults
                      else "inactive" if not self.active else "not the client holding control")
            return RampChannel.Result(success=False, message=f"{goal.channel}: {reason}")
        self.ramps.append((goal.channel, goal.target))
        start, slew = channel.measured_voltage, goal.slew_rate or DEFAULT_SLEW_RATE
        duration = 1.875 * abs(goal.target - start) / slew
        fault = self.fault_during_ramp
        t0 = time.monotonic()
        channel.target, channel.ramping = goal.target, True
        while True:
            progress = 1.0 if duration == 0 else min(1.0, (time.monotonic() - t0) / duration)
            if fault is not None and fault[:2] == (goal.channel, goal.target) and progress >= 0.5:
                self.fault_during_ramp = None
                self.latch(fault[2], HvChannelState.FAULT_OVER_CURRENT, "OVER_CURRENT")
                fault = None
            if channel.faults:
                goal_handle.abort()
                return RampChannel.Result(success=False, message=f"{goal.channel}: fault", final_voltage=0.0)
            if goal_handle.is_cancel_requested:
                self.set_voltage(channel, 0.0)  # cancel ramps down (instantly here)
                channel.ramping = False
                goal_handle.canceled()
                return RampChannel.Result(success=False, message="canceled", final_voltage=0.0)
            self.set_voltage(channel, start + (goal.target - start) * progress)
            goal_handle.publish_feedback(RampChannel.Feedback(
                setpoint=channel.setpoint, measured_voltage=channel.measured_voltage, progress=progress))
            if progress >= 1.0:
                break
            time.sleep(STEP)
        with self.lock:
            channel.ramping = False
            channel.output_enabled = goal.target > 0.0
        goal_handle.succeed()
        return RampChannel.Result(success=True, message="reached", final_voltage=channel.measured_voltage)

    def execute_pulse(self, goal_handle):
        """The train as square steps of the fake outputs; a fault or cancel ends it with the outputs at 0 V."""
        goal = goal_handle.request
        channels = [self.channels.get(name) for name in goal.channels]
        edge = {PulseChannels.Goal.EDGE_SMOOTH: "smooth", PulseChannels.Goal.EDGE_SQUARE: "square"}.get(goal.edge)
        command = pulse_command(list(goal.channels), goal.amplitude, goal.frequency, goal.duty, goal.phase,
                                goal.cycles, edge, goal.slew_rate)
        if None in channels or any(c.faults for c in channels) or not self.obeyed(goal, command):
            goal_handle.abort()
            return PulseChannels.Result(success=False, message="refused: unknown channel, faults or not in control")
        self.pulses.append((tuple(goal.channels), goal.cycles))
        period, t0 = 1.0 / goal.frequency, time.monotonic() + goal.phase / goal.frequency
        while (elapsed := time.monotonic() - t0) < goal.cycles * period:
            if any(c.faults for c in channels) or goal_handle.is_cancel_requested:
                for channel in channels:
                    self.set_voltage(channel, 0.0)
                canceled = goal_handle.is_cancel_requested
                goal_handle.canceled() if canceled else goal_handle.abort()
                return PulseChannels.Result(success=False, message="canceled" if canceled else "fault")
            on = elapsed >= 0 and (elapsed % period) < goal.duty * period
            for channel in channels:
                self.set_voltage(channel, goal.amplitude if on else 0.0)
            time.sleep(STEP)
        for channel in channels:
            self.set_voltage(channel, 0.0)
        goal_handle.succeed()
        return PulseChannels.Result(success=True, message="completed", cycles_done=goal.cycles,
                                    frequency=goal.frequency, generated_by="loop")
