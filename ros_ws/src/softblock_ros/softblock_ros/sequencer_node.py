"""Sequencer node: action `sequencer/run` executes a YAML manipulation sequence step by step.

Loads <sequences_dir>/<name>.yaml (a goal names a sequence, never a path), runs it with the sequencing
engine against the arm (`arm/move`) and the HV driver (`hv/ramp`, `hv/state`, `hv/estop`), publishes
feedback and a `sequencer/events` message per step transition. It holds control of the HV driver while a sequence runs
(`hv/claim_control`, then `hv/heartbeat` at `heartbeat_rate_hz`, `hv/release_control` at the end).
One goal at a time: a second goal is rejected while one runs. One sequencer at a time: a goal goes to every node that
serves sequencer/run, and its caller takes whichever answer comes first, so of two that both accepted it one could run
the sequence while the caller got the other's abort. A sequencer therefore serves only once it has looked for another
for `discovery_period_s` and found none (no server of sequencer/run, no other node of its name and namespace); while
there is one it stands by (logged) and serves once it is alone: of two, the first serves, two started together both
stand by. Should two serve all the same (other names, discovery slower than the period), both reject every goal.
SIGINT / SIGTERM cancel a running sequence first: its safe stop ramps
every channel to 0 V and control is released, then the node shuts down (a second signal shuts it down at once).
See docs/sequences.md.
"""
import signal
import threading
import time

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from softblock_interfaces.action import RunSequence
from softblock_interfaces.msg import SequenceEvent

from sequencing.engine import SequenceEngine, StepEvent
from sequencing.ports import RobotError, RunOptions
from sequencing.schema import Limits, SequenceError, StepDefaults, load_sequence

from .parameters import Param, declare
from .paths import resolve_path
from .ros_robot import RosRobot
from .runner import run_node

FEEDBACK_PHASES = {"precondition", "running", "awaiting_operator", "succeeded"}
RESULT_GRACE_S = 1.0  # [s] after a goal stopped by a signal ended, for its result to reach the caller
EVENT_PHASES = {"running": "started", "awaiting_operator": "awaiting_operator", "succeeded": "succeeded",
                "failed": "failed", "canceled": "canceled"}

PARAMETERS = (
    Param("sequences_dir", "sequences", "directory of <name>.yaml files, the only ones a goal can name (relative "
          "and not found from the working directory: the shipped config/sequences)", kind=str),
    Param("heartbeat_rate_hz", 10.0, "hv/heartbeat rate while a sequence runs", "Hz", 1.0, 100.0),
    Param.of(Limits, "voltage_ceiling_v", "highest voltage a sequence may command", "V", 0.0, 10000.0),
    Param.of(Limits, "max_pulse_frequency_hz", "highest pulse-train frequency", "Hz", 0.1, 50.0),
    Param.of(Limits, "max_slew_rate_v_per_s", "HV driver slew limit checked at load; 0 = left to the driver", "V/s",
             0.0, 1e6, none_as=0.0),
    Param.of(StepDefaults, "default_tolerance_v", "voltage tolerance of steps that give none", "V", 1.0, 1000.0,
             field="tolerance_v"),
    Param.of(StepDefaults, "default_timeout_s", "timeout of steps that give none", "s", 0.1, 3600.0,
             field="timeout_s"),
    Param.of(RunOptions, "settle_time_s", "how long a precondition may take to become true", "s", 0.0, 60.0),
    Param.of(RunOptions, "poll_period_s", "fault / cancel / timeout check period", "s", 0.001, 1.0),
    Param.of(RunOptions, "safe_stop_timeout_s", "time allowed for ramping every channel to 0 V", "s", 0.1, 600.0),
    Param.of(RunOptions, "off_voltage_v", "a disabled output below this needs no ramp-down in a safe stop", "V",
             0.0, 1000.0),
    # A stack started at once on a loaded host can take seconds to discover its servers; a reply lost on a lossy link
    # is resent only at the writer's next periodic heartbeat (3 s, docs/two_machines.md).
    Param("server_timeout_s", 10.0, "wait for the arm/move, hv/ramp, hv/estop servers", "s", 0.1, 60.0),
    Param("state_timeout_s", 2.0, "hv/state older than this counts as a link fault", "s", 0.05, 10.0),
    Param("discovery_period_s", 2.0, "how long a starting sequencer looks for another one before it serves "
          "sequencer/run, and how often it looks again while there is one", "s", 0.1, 60.0),
    Param("hv_driver_node", "hv_driver", "the HV driver's lifecycle node, deactivated (every output off) while an "
          "operator swaps blocks", kind=str),
)


class SequencerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("sequencer", **kwargs)
        value = declare(self, PARAMETERS)
        self._sequences_dir = resolve_path(value["sequences_dir"])
        self._limits = Limits(value["voltage_ceiling_v"], value["max_pulse_frequency_hz"],
                              value["max_slew_rate_v_per_s"] or None)
        self._defaults = {"tolerance": value["default_tolerance_v"], "timeout": value["default_timeout_s"]}
        self._options = RunOptions(value["poll_period_s"], value["settle_time_s"], value["safe_stop_timeout_s"],
                                   value["off_voltage_v"])
        group = ReentrantCallbackGroup()
        self._robot = RosRobot(self, group, value["server_timeout_s"], value["state_timeout_s"],
                               value["heartbeat_rate_hz"], value["hv_driver_node"])
        self._events = self.create_publisher(SequenceEvent, "sequencer/events", 10)
        self._busy = threading.Lock()
        self._cancel = threading.Event()
        self._running_name = ""
        self._stop_signal: int | None = None  # the signal that asked the node to stop
        self._stop_asked, self._stop_now = threading.Event(), threading.Event()
        # The longest a safe stop may take: the ramp-down, then the release of control.
        self._stop_timeout_s = value["safe_stop_timeout_s"] + value["server_timeout_s"]
        self._server_name = self.resolve_topic_name("sequencer/run")
        self._server: ActionServer | None = None
        self.serving, self.standing_by = threading.Event(), threading.Event()
        self._other = ""  # why it stands by, as last logged
        self._look = self.create_timer(value["discovery_period_s"], lambda: self._serve_when_alone(group),
                                       callback_group=MutuallyExclusiveCallbackGroup())

    def destroy_node(self):
        if self._server is not None:
            self._server.destroy()  # rclpy's destroy_node leaves action servers serving, and clients
        self._robot.destroy()
        return super().destroy_node()

    def _other_sequencer(self) -> str:
        """What would take this node's goals too, or "" when nothing does."""
        servers = self.count_publishers(f"{self._server_name}/_action/status")  # one per action server
        if servers:
            return f"{servers} other node(s) serve {self._server_name}"
        namesakes = self.get_node_names_and_namespaces().count((self.get_name(), self.get_namespace()))
        return f"{namesakes} nodes are named {self.get_fully_qualified_name()}" if namesakes > 1 else ""

    def _serve_when_alone(self, group) -> None:
        """Each discovery period until it serves: serve sequencer/run once no other sequencer is there."""
        other = self._other_sequencer()
        if other:
            if other != self._other:
                self.get_logger().warning(f"not serving {self._server_name}: {other}, and a goal would go to each; "
                                          "standing by until this node is the only one (stop all but one)")
            self._other = other
            self.standing_by.set()
            return
        self.destroy_timer(self._look)
        self._server = ActionServer(self, RunSequence, "sequencer/run", execute_callback=self._execute_in_thread,
                                    goal_callback=self._on_goal, cancel_callback=self._on_cancel,
                                    callback_group=group)
        self.standing_by.clear()
        self.serving.set()
        self.get_logger().info(f"serving {self._server_name}")

    def stop_safely_on_signals(self) -> None:
        """SIGINT / SIGTERM: the running sequence's safe stop first, then shutdown (call from the main thread).

        rclpy's own handler would shut the context down at once, and the sequence's safe stop could then send
        nothing (its ramps and the release fail on a shut-down context): only the driver's watchdog would bring
        the voltage down. This handler only sets an event: a thread of its own does the rest."""
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._on_signal)
        threading.Thread(target=self._stop_when_asked, name="sequencer stop", daemon=True).start()

    def _on_signal(self, signum, _frame) -> None:
        if self._stop_asked.is_set():
            self._stop_now.set()
        self._stop_signal = signum
        self._stop_asked.set()

    def _stop_when_asked(self) -> None:
        self._stop_asked.wait()
        name = signal.Signals(self._stop_signal).name
        running = self._busy.locked()
        if running:
            self.get_logger().warning(f"{name}: canceling sequence {self._running_name!r} (safe stop: every channel "
                                      f"to 0 V, control released), then shutting down")
            self._cancel.set()
        deadline = time.monotonic() + self._stop_timeout_s
        while not self._busy.acquire(timeout=0.05):  # held from now on: no goal starts any more
            if self._stop_now.is_set() or time.monotonic() > deadline:
                self.get_logger().error(f"{name}: shutting down before the safe stop ended")
                break
        else:
            if running:  # its result leaves in an executor task after its callback returned: let it go out
                self._stop_now.wait(RESULT_GRACE_S)
        self.get_logger().info(f"{name}: shutting down")
        self.context.try_shutdown()

    def _on_goal(self, goal: RunSequence.Goal) -> GoalResponse:
        servers = self.count_publishers(f"{self._server_name}/_action/status")  # one per action server
        if servers > 1:
            self.get_logger().error(f"rejected sequence {goal.sequence!r}: {servers} nodes serve "
                                    f"{self._server_name}, and each would run it; stop all but one")
            return GoalResponse.REJECT
        if self._stop_asked.is_set():
            self.get_logger().warning(f"rejected sequence {goal.sequence!r}: the sequencer is shutting down")
            return GoalResponse.REJECT
        if not self._busy.acquire(blocking=False):
            self.get_logger().warning(f"rejected sequence {goal.sequence!r}: "
                                      f"sequence {self._running_name!r} is still running")
            return GoalResponse.REJECT
        self._running_name = goal.sequence
        self._cancel.clear()
        return GoalResponse.ACCEPT

    def _on_cancel(self, _goal_handle) -> CancelResponse:
        self._cancel.set()
        return CancelResponse.ACCEPT

    def _on_step(self, goal_handle, event: StepEvent) -> None:
        if event.phase in FEEDBACK_PHASES:
            goal_handle.publish_feedback(RunSequence.Feedback(
                step_index=event.index, step_count=event.count, step_name=event.name,
                description=event.description, phase=event.phase))
        if event.phase in EVENT_PHASES:
            msg = SequenceEvent(sequence=event.sequence, step_index=event.index, step_name=event.name,
                                phase=EVENT_PHASES[event.phase], message=event.message)
            msg.header.stamp = self.get_clock().now().to_msg()
            self._events.publish(msg)
        text = f"{event.sequence} [{event.index + 1}/{event.count}] {event.name}: {event.phase} {event.message}"
        if event.phase in ("failed", "canceled"):  # rclpy wants one severity per logging call site
            self.get_logger().error(text)
        else:
            self.get_logger().info(text)

    async def _execute_in_thread(self, goal_handle) -> RunSequence.Result:
        """The sequence blocks a thread of its own for its whole run; the executor's single thread awaits its
        result meanwhile and serves hv/state, the heartbeat and the action clients' replies (a
        MultiThreadedExecutor would do the same at several times the CPU: rclpy 7.1's wakes its thread many
        times per callback)."""
        result, executor = Future(), self.executor

        def run() -> None:
            try:
                result.set_result(self._execute(goal_handle))
            except BaseException as error:  # the awaiting task raises it, logged by the executor's spinner
                result.set_exception(error)
            finally:
                executor.wake()  # a Future does not wake the executor that awaits it
        threading.Thread(target=run, name=f"sequence {goal_handle.request.sequence}", daemon=True).start()
        return await result

    def _execute(self, goal_handle) -> RunSequence.Result:
        try:
            try:
                sequence = load_sequence(goal_handle.request.sequence, self._sequences_dir, self._limits,
                                         self._defaults)
            except SequenceError as error:
                goal_handle.abort()
                return RunSequence.Result(success=False, message=f"rejected: {error}")
            try:
                self._robot.take_control()
            except RobotError as error:
                goal_handle.abort()
                return RunSequence.Result(success=False, message=str(error))
            try:
                engine = SequenceEngine(self._robot, self._options, lambda event: self._on_step(goal_handle, event))
                outcome = engine.run(sequence, self._cancel)
            finally:
                self.get_logger().info(f"HV control: {self._robot.give_up_control()}")
            result = RunSequence.Result(success=outcome.success, message=outcome.message,
                                        failed_step=outcome.failed_step, step_names=outcome.step_names,
                                        step_durations=outcome.step_durations)
            if outcome.canceled and not goal_handle.is_cancel_requested:  # stopped by a signal, not by its client
                result.message = f"sequencer stopped: {outcome.message}"
                goal_handle.abort()
            elif outcome.canceled:
                goal_handle.canceled()
            elif outcome.success:
                goal_handle.succeed()
            else:
                goal_handle.abort()
            return result
        finally:
            self._busy.release()


def main(args=None) -> int:
    def make_node() -> SequencerNode:
        node = SequencerNode()
        node.stop_safely_on_signals()
        return node
    return run_node(make_node, "sequencer", args=args)  # a SingleThreadedExecutor: see _execute_in_thread


if __name__ == "__main__":
    raise SystemExit(main())
