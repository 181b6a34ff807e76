"""HV driver node (lifecycle): the safety-supervised HV supply behind ROS topics, services and an action.

The supplies, the safety supervisor and the control loop run in a supervisor process of their own, without rclpy
(`hv_driver.server`; backend ``sim``: `sim_fallback.supervised`, which also runs the simulated supplies, one per
supply the channels name; ``serial``: the ``ports`` parameter). This node is its client (`hv_driver.RemoteSupply`):
when the node dies, the supervisor ramps every energised output down (NODE_LOST); when the supervisor dies, the node
reports SUPERVISOR_LOST and refuses every client.

configure = start the supervisor process, which opens and identifies the supplies; activate = outputs on at 0 V;
deactivate = ramp to 0 V and off; cleanup / shutdown = close (outputs off, supervisor ended); error = outputs off at
once. Only the client holding control (hv/claim_control) may ramp (hv/ramp), run pulse trains (hv/pulse: on the
device where it switches itself, else in the driver's loop) and feed the heartbeat watchdog; hv/estop is open to
everyone.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import sys

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import QoSProfile, ReliabilityPolicy
from softblock_interfaces.action import PulseChannels, RampChannel
from softblock_interfaces.msg import HvHeartbeat, HvState
from softblock_interfaces.srv import ClaimControl, InjectFault, ReleaseControl
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from hv_driver import HvError, RemoteSupply, SupervisorLostError
from hv_driver.control import session_id, signed
from hv_driver.socket_path import node_socket_path

from . import PUBLICATION_MODE, PUBLICATION_MODE_VARIABLE
from .hv_conversions import diagnostics_msg, hv_state_msg
from .hv_parameters import PARAMETERS, channel_configs, device_count
from .hv_pulse_goal import execute_pulse_goal
from .hv_ramp_goal import execute_ramp_goal
from .log_forwarding import forward_logging, stop_forwarding
from .parameters import ParameterError, declare
from .qos import LATCHED, stream_qos
from .runner import run_node

# A heartbeat is a sign of life: the newest counts. Taken reliably, one lost on a lossy link would hold up
# the ones behind it until it is repaired (over a second measured on a 5 % lossy link, up to the writer's 3 s
# heartbeat period), which the watchdog would take for a silent client.
HEARTBEAT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
SUPERVISOR_COMMANDS = {"sim": [sys.executable, "-m", "sim_fallback.supervised"],
                       "serial": [sys.executable, "-m", "hv_driver.server"]}
SIM_CHANNELS = 4  # a simulated multi-channel supply models a 4-channel module; configured indices must exist on it
REFUSAL_LOG_PERIOD = 5.0  # [s] at most one log line per kind of ignored heartbeat


class HvDriverNode(LifecycleNode):
    def __init__(self, **kwargs):
        super().__init__("hv_driver", **kwargs)
        self._settings = declare(self, PARAMETERS)
        self._channels = channel_configs(self._settings)
        self._devices = device_count(self._channels)
        ports = self._settings["ports"]
        if self._settings["backend"] == "serial" and len(ports) != self._devices:
            raise ParameterError(f"parameter ports={ports} refused: backend 'serial' needs one port per supply the "
                                 f"channels are on ({self._devices}), e.g. [/dev/ttyUSB0]")
        self._supply = None
        self._entities = []
        self._active = False
        self._group = ReentrantCallbackGroup()
        self._log_handler = forward_logging("hv_driver", self.get_logger())  # e.g. "heartbeat watchdog OFF"

    def _param(self, name):
        return self._settings[name]

    # --- lifecycle -------------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        backend, ports, channels = self._param("backend"), self._param("ports"), self._channels
        if not self._param("expected_identity"):
            self.get_logger().warning("expected_identity is empty: the supply's identity is not checked")
        if (mode := os.environ.get(PUBLICATION_MODE_VARIABLE)) != PUBLICATION_MODE:
            self.get_logger().warning(f"{PUBLICATION_MODE_VARIABLE}={mode}: a reader that stops answering can block "
                                      f"hv/state's publish, and with it the control loop, for up to 1 s "
                                      f"({PUBLICATION_MODE} never blocks)")
        try:
            # A heartbeat_timeout_s of .inf (watchdog off) is warned by the supervisor itself at open.
            self._supply = RemoteSupply(SUPERVISOR_COMMANDS[backend], self._supervisor_spec(),
                                        self._socket_path(), on_lost=self._on_supervisor_lost).open()
        except (HvError, OSError) as error:
            self.get_logger().fatal(f"configure failed: {error}")
            self._stop()
            return FAILURE
        ports = [port for port in self._supply.snapshot().port.split(", ") if port]
        self._index = {c.name: (c.index, c.device) for c in channels}
        self._published, self._diag_time = None, 0
        self._state_pub = self.create_publisher(HvState, "hv/state", stream_qos(self._param("publish_rate_hz")))
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        g = self._group
        self._entities = [
            self._state_pub, self._diag_pub,
            # Its own exclusive group: a late callback never overlaps the next, so hv/state stays in order.
            self.create_timer(1.0 / self._param("publish_rate_hz"), self._publish,
                              callback_group=MutuallyExclusiveCallbackGroup()),
            self.create_service(Trigger, "hv/estop", self._on_estop, callback_group=g),
            self.create_service(Trigger, "hv/reset_faults", self._on_reset, callback_group=g),
            self.create_service(InjectFault, "hv/inject_fault", self._on_inject, callback_group=g),
            self.create_service(ClaimControl, "hv/claim_control", self._on_claim, callback_group=g),
            self.create_service(ReleaseControl, "hv/release_control", self._on_release, callback_group=g),
            self.create_subscription(HvHeartbeat, "hv/heartbeat", self._on_heartbeat, HEARTBEAT_QOS,
                                     callback_group=g),
            self.create_subscription(Float64, "assembly/safe_voltage", self._on_safe_voltage, LATCHED, callback_group=g),
            ActionServer(self, RampChannel, "hv/ramp", self._execute_ramp, callback_group=g,
                         cancel_callback=lambda _: CancelResponse.ACCEPT),
            ActionServer(self, PulseChannels, "hv/pulse", self._execute_pulse, callback_group=g,
                         cancel_callback=lambda _: CancelResponse.ACCEPT)]
        self.get_logger().info(f"configured: {self._supply.device_id} on {', '.join(ports)} ({backend}), supervisor "
                               f"process {self._supply.pid}")
        return SUCCESS

    def _supervisor_spec(self) -> dict:
        """What the supervisor process builds its HvSupply from (hv_driver.server.supply_from_spec)."""
        spec = {"ports": self._param("ports"), "baudrate": self._param("baudrate") or None,
                "channels": [dataclasses.asdict(c) for c in self._channels], "dialect": self._param("dialect"),
                **{name: self._param(name) for name in ("loop_rate_hz", "link_timeout_s", "heartbeat_timeout_s",
                                                        "expected_identity", "realtime_priority", "orphan_timeout_s")},
                "keepalive_timeout_s": self._param("node_keepalive_timeout_s")}
        if self._param("backend") == "sim":
            spec["simulated"] = {"channels": SIM_CHANNELS, "devices": self._devices, "link": self._param("sim_link")}
        return spec

    def _socket_path(self) -> str:
        """The supervisor_socket parameter, else the path fixed by this node's name, domain and ports: either way a
        node started again (a respawn after its death) takes over the supervisor that still holds its supplies."""
        if self._param("supervisor_socket"):
            return self._param("supervisor_socket")
        return node_socket_path(self.get_fully_qualified_name(), self.context.get_domain_id(), self._param("ports"))

    def _on_supervisor_lost(self, reason: str) -> None:
        self.get_logger().fatal(f"HV supervisor process lost ({reason}): hv/state reports SUPERVISOR_LOST on every "
                                f"channel and every client is refused; only the supplies' own means still hold")

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Outputs on at 0 V, except those with latched faults (a supervisor taken over after its node was lost):
        they stay off until hv/reset_faults."""
        faulted = {c.name: c.fault_text for c in self._supply.snapshot().channels if c.faults}
        try:
            for name in self._index:
                if name not in faulted:
                    self._supply.enable(name)
        except HvError as error:
            self.get_logger().error(f"activate refused: {error}")
            return FAILURE
        for name, text in faulted.items():
            self.get_logger().error(f"channel {name!r} stays off until hv/reset_faults: {text}")
        self._active = True
        self.get_logger().info("active: outputs on at 0 V")
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self._active = False
        try:
            for name in self._index:
                self._supply.disable(name)
            if not self._supply.wait_outputs_off(timeout=30.0):
                self.get_logger().error("deactivate: outputs still on after 30 s")
                return FAILURE
        except HvError as error:  # the supervisor process lost
            self.get_logger().error(f"deactivate refused: {error}")
            return FAILURE
        self.get_logger().info("inactive: outputs ramped to 0 V and off")
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._stop()
        self.get_logger().info("unconfigured: outputs off, supplies closed")
        return SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self._stop()
        self.get_logger().info("shut down: outputs off, supplies closed")
        return SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        if self._supply is not None:
            self._supply.abort()
        self._stop()
        self.get_logger().error("error: outputs switched off at once, supplies closed")
        return SUCCESS

    def _stop(self) -> None:
        """Outputs ramped to 0 V and off, port closed, simulated supply stopped, entities destroyed."""
        self._active = False
        for entity in self._entities:
            entity.destroy() if isinstance(entity, ActionServer) else self._destroy(entity)
        self._entities = []
        if self._supply is not None:
            self._supply.close()
        self._supply = None

    def _destroy(self, entity) -> None:
        for destroy in (self.destroy_publisher, self.destroy_timer, self.destroy_service, self.destroy_subscription):
            if destroy(entity):
                return

    def destroy_node(self):
        self._stop()
        stop_forwarding("hv_driver", self._log_handler)
        return super().destroy_node()

    # --- topics, services, action ----------------------------------------------------------------
    def _publish(self) -> None:
        events = self._supply.drain_events()  # faults latched or cleared, control lapsed, even between snapshots
        snapshot, stamp = self._supply.snapshot(), self.get_clock().now().to_msg()
        for event in events:
            self._log(event.level, f"{event.text} ({max(snapshot.stamp - event.time, 0.0):.3f} s ago)")
        self._state_pub.publish(hv_state_msg(snapshot, self._param("backend"), stamp))
        shown = (snapshot.controller, tuple(int(c.faults) for c in snapshot.channels))
        now = self.get_clock().now().nanoseconds
        if shown != self._published or now - self._diag_time >= 1e9:  # 1 Hz, and at once on a fault or owner change
            self._published, self._diag_time = shown, now
            self._diag_pub.publish(diagnostics_msg(snapshot, self.get_name(), self._param("backend"), stamp))

    def _log(self, level: int, line: str) -> None:
        """``line`` at a `logging` level (rclpy wants one severity per call site)."""
        if level >= logging.ERROR:
            self.get_logger().error(line)
        elif level >= logging.WARNING:
            self.get_logger().warning(line)
        else:
            self.get_logger().info(line)

    def _on_estop(self, request, response):
        try:
            self._supply.estop()
        except HvError as error:  # the supervisor process lost: the refusal names the fault
            response.success, response.message = False, f"emergency stop refused: {error}"
            return response
        response.success, response.message = True, "emergency stop latched: every output 0 V and off"
        return response

    def _on_reset(self, request, response):
        try:
            names = self._supply.reset_faults()  # only the faulted channels: healthy outputs keep their voltage
        except HvError as error:  # the supervisor process lost
            response.success, response.message = False, f"reset refused: {error}"
            return response
        response.success, response.message = True, f"faults cleared on {names}; those outputs off"
        if self._active:
            try:
                for name in names:
                    self._supply.enable(name)
                response.message = f"faults cleared on {names}; those outputs on at 0 V (active)"
            except HvError as error:
                response.success, response.message = False, f"faults cleared on {names}, enabling refused: {error}"
        return response

    def _on_claim(self, request, response):
        try:
            response.token = self._supply.claim_control(request.client, request.nonce)
        except HvError as error:  # another client holds control, or a name that cannot be shown
            response.success, response.message = False, str(error)
            return response
        response.session = session_id(response.token)
        response.heartbeat_timeout = self._supply.snapshot().heartbeat_timeout_s
        response.success, response.message = True, f"control held by {request.client!r}"
        self.get_logger().info(response.message)
        return response

    def _on_release(self, request, response):
        try:
            client = self._supply.release_control(signed(request.session, request.counter, request.mac))
        except HvError as error:  # not the live session's, or a copied or replayed release
            response.success, response.message = False, str(error)
            return response
        response.success, response.message = True, f"control released by {client!r}; its energised outputs ramp to 0 V"
        self.get_logger().info(response.message)
        return response

    def _on_heartbeat(self, msg: HvHeartbeat) -> None:
        """Forwarded at once, without waiting for the supervisor's answer: it counts from now even while the
        supervisor stalls."""
        try:
            self._supply.forward_heartbeat(signed(msg.session, msg.counter, msg.mac), self._heartbeat_refused)
        except HvError as error:  # the supervisor process lost
            self._heartbeat_refused(error)

    def _heartbeat_refused(self, error: Exception) -> None:
        """Another client, an ended session, a copied heartbeat, a replayed recording, a lost supervisor."""
        self.get_logger().warning(f"hv/heartbeat ignored: {error}", throttle_duration_sec=REFUSAL_LOG_PERIOD)

    def _on_inject(self, request, response):
        try:
            if self._param("backend") != "sim":
                raise ValueError(f"inject_fault needs backend 'sim', this node runs {self._param('backend')!r}")
            if request.fault == "clear":
                self._supply.clear_faults()
            else:
                address = self._index.get(request.channel)
                if request.channel and address is None:
                    raise ValueError(f"channel={request.channel!r}: unknown, configured are {sorted(self._index)}")
                self._supply.inject_fault(request.fault, *(address or (None, None)))
            response.success, response.message = True, f"injected {request.fault} on {request.channel or 'the device'}"
        except (HvError, ValueError) as error:
            response.success, response.message = False, str(error)
        return response

    def _on_safe_voltage(self, msg: Float64) -> None:
        try:
            self._supply.set_safe_voltage(msg.data)
        except SupervisorLostError as error:
            self.get_logger().error(f"assembly/safe_voltage refused: {error}")
        except HvError as error:  # an unusable ceiling blocks all voltage rather than none
            self.get_logger().error(f"assembly/safe_voltage: {error}; ceiling set to 0 V")
            self._supply.set_safe_voltage(0.0)

    def _execute_ramp(self, goal_handle):
        if not self._active:
            goal_handle.abort()
            return RampChannel.Result(message="hv_driver is not active")
        return execute_ramp_goal(self._supply, goal_handle)

    def _execute_pulse(self, goal_handle):
        if not self._active:
            goal_handle.abort()
            return PulseChannels.Result(message="hv_driver is not active")
        return execute_pulse_goal(self._supply, goal_handle)


def main(args=None) -> int:
    def make_node():
        node = HvDriverNode()
        try:
            if node.get_parameter("autostart").value and (
                    node.trigger_configure() != SUCCESS or node.trigger_activate() != SUCCESS):
                raise ValueError("autostart: configure/activate failed (see the log above)")
        except BaseException:
            # also a Ctrl-C landing in a transition (rclpy raises from the shut-down context): run_node never gets
            # this node, so it is destroyed here, which closes the supply and ends its supervisor process
            node.destroy_node()
            raise
        return node
    # Threads for the ramp goals (each waits on its ramp), services and the state timer.
    return run_node(make_node, "hv_driver", lambda: MultiThreadedExecutor(num_threads=8), args=args)


if __name__ == "__main__":
    raise SystemExit(main())
