"""The sequencing engine's `Robot` on ROS: `arm/move`, `hv/ramp` and `hv/pulse` action clients, `hv/state`, `hv/estop`,
the operator's `sequencer/operator_done` with the estimator's verdict (`operator_wait`), control of the HV driver
(`HvControl`: claimed for a sequence, heartbeats while held), and the driver's lifecycle (`<hv_driver>/change_state`:
inactive, every output off, while an operator swaps blocks).

Nothing here blocks on the executor: goals are sent with futures whose callbacks set a
threading.Event, so the engine can wait in a thread of its own while the executor's thread serves the callbacks.
"""
from __future__ import annotations

import threading
import time

from action_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from softblock_interfaces.action import MoveArm, PulseChannels, RampChannel
from softblock_interfaces.msg import HvChannelState, HvState
from std_srvs.srv import Trigger

from sequencing.ports import ChannelReading, Outcome, RobotError

from .client import ActionClient, ClientError, call_service
from .conversions import pose_msg
from .hv_control import HvControl
from .operator_wait import OperatorDesk, OperatorRequest


class ActionMotion:
    """One action goal seen as an engine `Motion`; ``to_outcome(status, result)`` reads its result."""

    def __init__(self, client: ActionClient, goal, to_outcome):
        self._to_outcome = to_outcome
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._outcome: Outcome | None = None
        self._handle = None
        self._cancel_requested = False
        client.send_goal_async(goal).add_done_callback(self._on_goal_response)

    def _finish(self, outcome: Outcome) -> None:
        self._outcome = outcome
        self._done.set()

    def _on_goal_response(self, future) -> None:
        handle = future.result()
        if not handle.accepted:
            self._finish(Outcome(False, "goal rejected by the server"))
            return
        with self._lock:
            self._handle = handle
            cancel = self._cancel_requested
        if cancel:
            handle.cancel_goal_async()
        handle.get_result_async().add_done_callback(
            lambda result: self._finish(self._to_outcome(result.result().status, result.result().result)))

    def wait(self, timeout: float) -> bool:
        return self._done.wait(timeout)

    def outcome(self) -> Outcome:
        return self._outcome

    def cancel(self) -> None:
        with self._lock:
            self._cancel_requested = True
            handle = self._handle
        if handle is not None and not self._done.is_set():
            handle.cancel_goal_async()


def _ramp_outcome(status: int, result: RampChannel.Result) -> Outcome:
    return Outcome(status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message, result.final_voltage)


def _pulse_outcome(status: int, result: PulseChannels.Result) -> Outcome:
    success = status == GoalStatus.STATUS_SUCCEEDED and result.success
    how = f"{result.cycles_done} cycles at {result.frequency:g} Hz, switched by the {result.generated_by}"
    return Outcome(success, how if success else result.message)


def _move_outcome(status: int, result: MoveArm.Result) -> Outcome:
    return Outcome(status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message)


class RosRobot:
    """Adapts ROS clients of the arm and the HV driver to the engine's `Robot` interface."""

    def __init__(self, node: Node, callback_group, server_timeout: float, state_timeout: float,
                 heartbeat_rate_hz: float = 10.0, hv_driver_node: str = "hv_driver"):
        self._server_timeout, self._state_timeout = server_timeout, state_timeout
        self._control = HvControl(node, node.get_name(), heartbeat_rate_hz, callback_group, server_timeout)
        self._ramp = ActionClient(node, RampChannel, "hv/ramp", callback_group=callback_group)
        self._pulse = ActionClient(node, PulseChannels, "hv/pulse", callback_group=callback_group)
        self._move = ActionClient(node, MoveArm, "arm/move", callback_group=callback_group)
        self._estop = node.create_client(Trigger, "hv/estop", callback_group=callback_group)
        self._lifecycle = {kind: node.create_client(kind, f"{hv_driver_node}/{name}", callback_group=callback_group)
                           for kind, name in ((GetState, "get_state"), (ChangeState, "change_state"))}
        self._operator = OperatorDesk(node, callback_group)
        self._lock = threading.Lock()
        self._state: HvState | None = None
        self._state_time = 0.0
        self._arm_motion: ActionMotion | None = None
        self._logger = node.get_logger()
        self._lost_reported = False  # the driver's silence is logged once, when first seen
        # Best effort: the engine wants the newest state. A reliable subscription holds newer samples back behind
        # one a lossy link dropped until the driver repairs it (seconds: its next periodic heartbeat), and the
        # state would look stale.
        node.create_subscription(HvState, "hv/state", self._on_state, qos_profile_sensor_data,
                                 callback_group=callback_group)

    def destroy(self) -> None:
        """Destroy the action clients, which the node's destroy_node leaves (and with them the node in the graph)."""
        for client in (self._ramp, self._pulse, self._move):
            client.destroy()

    def _on_state(self, msg: HvState) -> None:
        with self._lock:
            self._state, self._state_time = msg, time.monotonic()
            returned, self._lost_reported = self._lost_reported, False
        if returned:
            self._logger.info("HV driver back: hv/state received again")

    def take_control(self) -> None:
        """Claim control of the HV driver (heartbeats while held); RobotError naming the holder if refused."""
        try:
            self._control.claim()
        except ClientError as error:
            raise RobotError(str(error)) from None

    def give_up_control(self) -> str:
        """Release control of the HV driver; returns the driver's answer (or why it did not answer)."""
        try:
            return self._control.release()
        except ClientError as error:
            return str(error)

    def _ready(self, client: ActionClient, name: str) -> None:
        if not client.wait_for_server(timeout_sec=self._server_timeout):
            raise RobotError(f"{name}: action server not available after {self._server_timeout:g} s")

    def move_arm(self, position, orientation, frame_id: str, speed: float) -> ActionMotion:
        self._ready(self._move, "arm/move")
        goal = MoveArm.Goal(target=PoseStamped(pose=pose_msg(position, orientation)), max_speed=float(speed))
        goal.target.header.frame_id = frame_id
        motion = ActionMotion(self._move, goal, _move_outcome)
        self._arm_motion = motion
        return motion

    def ramp(self, channel: str, target: float, slew_rate: float) -> ActionMotion:
        self._ready(self._ramp, "hv/ramp")
        return ActionMotion(self._ramp, self._signed(self._control.ramp_goal, channel, target, slew_rate),
                            _ramp_outcome)

    def pulse(self, channels, voltage: float, frequency: float, duty: float, phase: float, cycles: int, edge: str,
              slew_rate: float) -> ActionMotion:
        self._ready(self._pulse, "hv/pulse")
        goal = self._signed(self._control.pulse_goal, channels, voltage, frequency, duty, phase, cycles, edge,
                            slew_rate)
        return ActionMotion(self._pulse, goal, _pulse_outcome)

    @staticmethod
    def _signed(make_goal, *arguments):
        try:
            return make_goal(*arguments)
        except ClientError as error:  # control not held (lost to an e-stop, never claimed)
            raise RobotError(str(error)) from None

    def channel_states(self) -> dict[str, ChannelReading]:
        """Latest hv/state; a driver silent for longer than the state timeout (stopped, or the network to it
        down) shows as a link fault on every channel it reported."""
        with self._lock:
            state, age = self._state, time.monotonic() - self._state_time
            silent = state is not None and age > self._state_timeout
            newly_lost, self._lost_reported = silent and not self._lost_reported, self._lost_reported or silent
        if state is None:
            return {}
        if newly_lost:
            self._logger.error(f"HV driver lost: no hv/state for {age:.1f} s "
                               f"(state timeout {self._state_timeout:g} s)")
        readings = {}
        for channel in state.channels:
            faults, text = channel.faults, channel.fault_text
            if state.estop:
                faults, text = faults | HvChannelState.FAULT_ESTOP, text or "ESTOP"
            if silent:
                faults, text = faults | HvChannelState.FAULT_LINK, f"HV driver lost: no hv/state for {age:.1f} s"
            readings[channel.name] = ChannelReading(channel.measured_voltage, faults, text, channel.output_enabled,
                                                    stale=silent)
        return readings

    def hv_outputs(self, on: bool) -> Outcome:
        """The HV driver active (outputs on at 0 V) or inactive (every output ramped to 0 V and off, ramps refused);
        a driver already there is left as it is."""
        wanted, transition = ((State.PRIMARY_STATE_ACTIVE, Transition.TRANSITION_ACTIVATE) if on else
                              (State.PRIMARY_STATE_INACTIVE, Transition.TRANSITION_DEACTIVATE))
        get_state, change_state = self._lifecycle[GetState], self._lifecycle[ChangeState]
        try:
            current = call_service(get_state, GetState.Request(), self._server_timeout).current_state
            if current.id == wanted:
                return Outcome(True, f"the HV driver is already {current.label}")
            reply = call_service(change_state, ChangeState.Request(transition=Transition(id=transition)),
                                 self._server_timeout)
        except ClientError as error:
            return Outcome(False, str(error))
        if not reply.success:
            return Outcome(False, f"{change_state.srv_name}: the HV driver refused to "
                                  f"{'activate' if on else 'deactivate'} (it was {current.label})")
        return Outcome(True, "HV driver active: outputs on at 0 V" if on else "HV driver inactive: every output off")

    def request_operator(self, prompt: str) -> OperatorRequest:
        return self._operator.request(prompt)

    def stop_arm(self) -> None:
        """Cancel the running arm goal: the arm brakes and holds."""
        if self._arm_motion is not None:
            self._arm_motion.cancel()

    def estop(self) -> Outcome:
        if not self._estop.wait_for_service(timeout_sec=self._server_timeout):
            return Outcome(False, "hv/estop: service not available")
        done = threading.Event()
        future = self._estop.call_async(Trigger.Request())
        future.add_done_callback(lambda _: done.set())
        if not done.wait(self._server_timeout):
            return Outcome(False, "hv/estop: no reply")
        reply = future.result()
        return Outcome(reply.success, reply.message)
