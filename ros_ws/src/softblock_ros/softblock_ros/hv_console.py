"""HV console: watch the HV driver from any machine of the stack, and command it by hand.

    python -m softblock_ros.hv_console                      # one status line per second
    python -m softblock_ros.hv_console --json               # every hv/state sample and control status, JSON lines
    python -m softblock_ros.hv_console --commands           # also take commands on stdin
    python -m softblock_ros.hv_console --probe /dev/ttyUSB0  # which supply is on a port (read-only; no ROS)

The status line checks the link to the driver: hv/state samples received per second, samples lost on the way
(gaps in the driver's publication sequence numbers), the age of the newest, each channel, and from the
driver's /diagnostics who holds control and how long ago its last heartbeat arrived.

Commands, one per line, each answered with one line (a JSON object with --json):
    reset                     hv/reset_faults
    estop                     hv/estop
    claim <client name>       hv/claim_control; heartbeats follow while the console holds control
    ramp <channel> <volts>    hv/ramp signed for the console's session, waits for the result
    release                   hv/release_control
    activate | deactivate     the driver's lifecycle (hv_driver/change_state): outputs on at 0 V | all off (as
                              `ros2 lifecycle set /hv_driver activate`, for the wheel set-up without the ros2 CLI)
    quit                      (also end of input): control still held is released first (after Ctrl-C the
                              driver's heartbeat watchdog ends it)
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from softblock_interfaces.action import RampChannel
from softblock_interfaces.msg import HvState
from std_srvs.srv import Trigger

from hv_driver import LinkError
from hv_driver.probe import probe, report

from .client import ActionClient, ClientError, call_service, run_action, status_name
from .hv_control import HvControl
from .hv_conversions import control_values
from .runner import init

# Best effort: a sample the link drops shows as lost instead of holding up the newer ones.
STATE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
SERVICE_TIMEOUT = 10.0  # [s]
TRANSITIONS = {"activate": Transition.TRANSITION_ACTIVATE, "deactivate": Transition.TRANSITION_DEACTIVATE}
RAMP_TIMEOUT = 600.0    # [s] the driver's slowest allowed ramp
MAX_COMMAND = 256       # [characters] of one command line


class HvConsole:
    """hv/state and /diagnostics in, one record (a dict) per sample, status and command answer out."""

    def __init__(self, node: Node, emit):
        self._emit = emit
        self._lock = threading.Lock()
        self._received = self._lost = 0
        self._last_sequence = None
        self._state: HvState | None = None
        self._state_time = 0.0
        self._control: dict | None = None
        node.create_subscription(HvState, "hv/state", self._on_state, STATE_QOS, raw=True)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self._reset = node.create_client(Trigger, "hv/reset_faults")
        self._estop = node.create_client(Trigger, "hv/estop")
        self._ramp = ActionClient(node, RampChannel, "hv/ramp")
        self._change_state = node.create_client(ChangeState, "hv_driver/change_state")
        self.control = HvControl(node, "hv_console", timeout_s=SERVICE_TIMEOUT)

    def _on_state(self, data: bytes, info: dict) -> None:
        msg, now = deserialize_message(data, HvState), time.time()
        sequence = info.get("publication_sequence_number")
        with self._lock:
            self._received += 1
            if sequence is not None and self._last_sequence is not None and sequence > self._last_sequence + 1:
                self._lost += sequence - self._last_sequence - 1
            self._last_sequence = sequence if sequence is not None else self._last_sequence
            self._state, self._state_time = msg, now
        self._emit({"type": "state", "t": now, "stamp": msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                    "sequence": sequence, "estop": msg.estop,
                    "channels": {c.name: {"voltage_v": c.measured_voltage, "setpoint_v": c.setpoint,
                                          "output_enabled": c.output_enabled, "faults": c.faults,
                                          "fault_text": c.fault_text} for c in msg.channels}})

    def _on_diagnostics(self, array: DiagnosticArray) -> None:
        values = control_values(array)
        if values is None:
            return
        with self._lock:
            self._control = values
        self._emit({"type": "control", "t": time.time(), **values})

    def take_counts(self) -> tuple[int, int]:
        """(samples received, samples lost) since the last call."""
        with self._lock:
            counts = self._received, self._lost
            self._received = self._lost = 0
        return counts

    def status_line(self, received: int, lost: int, period: float) -> str:
        with self._lock:
            state, age, control = self._state, time.time() - self._state_time, self._control
        if state is None:
            return "hv/state: nothing received yet"
        channels = "  ".join(f"{c.name} {c.measured_voltage:7.1f} V {'on ' if c.output_enabled else 'off'}"
                             + (f" [{c.fault_text}]" if c.faults else "") for c in state.channels)
        owner = "control: unknown (no /diagnostics yet)"
        if control is not None:
            owner = (f"control: {control['controller']!r}, last heartbeat {control['heartbeat_age_s']} s ago"
                     if control["controller"] else "control: free")
        return (f"hv/state {received / period:5.1f}/s, {lost} lost, newest {age:5.2f} s old | {channels} | "
                f"{owner}")

    def execute(self, line: str) -> dict:
        """Run one command; the answer as ``{"command", "ok", "message"}``."""
        words = line.split()
        command, arguments = (words[0], words[1:]) if words else ("", [])
        try:
            ok, message = self._run(command, arguments)
        except (ClientError, ValueError) as error:
            ok, message = False, str(error)
        return {"type": "reply", "command": line.strip(), "ok": ok, "message": message}

    def _run(self, command: str, arguments: list[str]) -> tuple[bool, str]:
        if command in ("reset", "estop") and not arguments:
            reply = call_service(self._reset if command == "reset" else self._estop, Trigger.Request(),
                                 SERVICE_TIMEOUT)
            return reply.success, reply.message
        if command == "claim" and arguments:
            self.control.client = " ".join(arguments)
            return True, f"control held, session {self.control.claim()}"
        if command == "release" and not arguments:
            return True, self.control.release()
        if command in TRANSITIONS and not arguments:
            reply = call_service(self._change_state, ChangeState.Request(transition=Transition(
                id=TRANSITIONS[command])), SERVICE_TIMEOUT)
            return reply.success, (f"hv_driver {command}d" if reply.success else
                                   f"hv_driver refused to {command} (is it {command}d already? see its log)")
        if command == "ramp" and len(arguments) == 2:
            goal = self.control.ramp_goal(arguments[0], float(arguments[1]))
            status, result = run_action(self._ramp, goal, RAMP_TIMEOUT, server_timeout=SERVICE_TIMEOUT)
            return result.success, f"{status_name(status)}: {result.message}"
        raise ValueError(f"unknown command {' '.join([command, *arguments])!r}; "
                         "known: reset, estop, claim <client>, ramp <channel> <volts>, release, activate, deactivate, quit")


def read_commands(console: HvConsole, emit, stop: threading.Event) -> None:
    for line in sys.stdin:
        if stop.is_set() or line.strip() == "quit":
            break
        if line.strip():
            emit(console.execute(line[:MAX_COMMAND]))
    stop.set()


def run_probe(port: str, baudrate: int | None) -> int:
    """Identify the supply on ``port`` without changing anything: 0 found, 1 nothing answered, 2 no such port."""
    try:
        result = probe(port, baudrate)
    except LinkError as error:
        print(error, file=sys.stderr)
        return 2
    print(report(result), flush=True)
    return 0 if result.found else 1


def main(argv=None) -> int:
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.hv_console", description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true", help="every sample and answer as a JSON line")
    parser.add_argument("--commands", action="store_true", help="read commands on stdin")
    parser.add_argument("--period", type=float, default=1.0, help="status line period [s] (default 1)")
    parser.add_argument("--probe", metavar="PORT", help="identify the supply on serial PORT with each dialect's "
                        "identification query (nothing is set), print the node parameters for it and exit")
    parser.add_argument("--baudrate", type=int, help="with --probe: ask at this rate (default: each dialect's own)")
    args = parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    if args.probe:
        return run_probe(args.probe, args.baudrate)
    output_lock, stop = threading.Lock(), threading.Event()

    def emit(record: dict) -> None:
        if args.json or record["type"] == "reply":
            text = json.dumps(record) if args.json else f"{'ok' if record['ok'] else 'FAILED'}: {record['message']}"
            with output_lock:
                print(text, flush=True)

    init(argv)
    node = rclpy.create_node("hv_console")
    console = HvConsole(node, emit)
    executor = SingleThreadedExecutor()  # a client: see softblock_ros.client
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    if args.commands:
        threading.Thread(target=read_commands, args=(console, emit, stop), daemon=True).start()
    try:
        while rclpy.ok() and not stop.wait(args.period):
            if not args.json:
                with output_lock:
                    print(console.status_line(*console.take_counts(), args.period), flush=True)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if console.control.session and rclpy.ok():
            try:
                console.control.release()
            except ClientError as error:
                print(f"release of control failed: {error}", file=sys.stderr)
        executor.shutdown(timeout_sec=5.0)
        spinner.join(timeout=5.0)  # a thread left inside rclpy at exit aborts the process (std::terminate)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
