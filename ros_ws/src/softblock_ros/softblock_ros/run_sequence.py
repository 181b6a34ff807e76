"""Command-line client of `sequencer/run` (stands in for `ros2 action send_goal`).

    python -m softblock_ros.run_sequence finger_grasp        # a name in the sequencer's sequences_dir
    python -m softblock_ros.run_sequence legged_gait --ros-args -r __ns:=/robot1

Prints each step transition, then the result with the per-step durations. Ctrl-C (or --timeout)
cancels the sequence (the sequencer ramps every channel down) and waits for the canceled result. When an
operator_swap step waits for the operator, Enter typed here confirms the swap (sequencer/operator_done, as
``ros2 service call /sequencer/operator_done std_srvs/srv/Trigger`` does where the ros2 CLI is installed).
Exit status: 0 succeeded, 1 failed or refused, 2 canceled, 3 no sequencer (or no reply).
"""
from __future__ import annotations

import argparse
import sys
import threading
import time

import rclpy
from action_msgs.msg import GoalStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from softblock_interfaces.action import RunSequence
from std_srvs.srv import Trigger

from .client import ActionClient, ClientError, call_service

SERVICE_TIMEOUT = 10.0  # [s] for the sequencer's answer to a confirmation


class Operator:
    """The operator at this terminal: a line typed while an operator_swap step waits confirms the swap."""

    def __init__(self, node, keyboard=sys.stdin):
        self._done = node.create_client(Trigger, "sequencer/operator_done")
        self._keyboard = keyboard
        self._asked = threading.Event()
        # held from a confirmation's request until its reply is printed: the swap it confirms may end the sequence,
        # and with it this program, before the reply comes in
        self._confirming = threading.Lock()
        self._keyboard_lost = threading.Event()  # standard input cannot be read (closed, or not a terminal's)

    def print_feedback(self, message) -> None:
        feedback = message.feedback
        print(f"[{feedback.step_index + 1}/{feedback.step_count}] {feedback.step_name}: {feedback.phase}"
              + (f"  ({feedback.description})" if feedback.phase == "running" and feedback.description else ""),
              flush=True)
        if feedback.phase == "awaiting_operator" and not self._asked.is_set():
            self._asked.set()  # before the prompt: a line typed in answer to it confirms
            confirm = ("call the service sequencer/operator_done to confirm" if self._keyboard_lost.is_set()
                       else "press Enter here to confirm")
            print(f"operator: {feedback.description}\nevery channel is at 0 V; make the swaps, then {confirm} "
                  "(Ctrl-C cancels the sequence)", flush=True)

    def listen(self) -> None:
        """Confirm a swap for each line typed while one is asked for (run in a daemon thread)."""
        try:
            self._confirm_each_line()
        except (OSError, ValueError):  # no readable standard input: confirmations come through the service
            self._keyboard_lost.set()

    def _confirm_each_line(self) -> None:
        for _ in self._keyboard:
            if not self._asked.is_set():
                print("operator: no swap is asked for now", flush=True)
                continue
            with self._confirming:
                self._asked.clear()
                try:
                    reply = call_service(self._done, Trigger.Request(), SERVICE_TIMEOUT)
                    print(f"operator: {reply.message}", flush=True)
                except ClientError as error:
                    print(f"operator: confirmation not delivered: {error}", file=sys.stderr, flush=True)
                    self._asked.set()

    def wait_for_confirmation(self) -> None:
        """Until the reply to a confirmation on its way is printed (a confirmation waits at most SERVICE_TIMEOUT)."""
        if self._confirming.acquire(timeout=SERVICE_TIMEOUT):
            self._confirming.release()


def run(sequence: str, server_timeout: float, timeout: float = 0.0) -> int:
    node = rclpy.create_node("run_sequence")
    executor = SingleThreadedExecutor()  # a client: see softblock_ros.client
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    operator = Operator(node)
    threading.Thread(target=operator.listen, daemon=True).start()
    try:
        return send(ActionClient(node, RunSequence, "sequencer/run"), sequence, server_timeout, timeout, operator)
    finally:
        executor.shutdown(timeout_sec=5.0)
        spinner.join(timeout=5.0)
        node.destroy_node()


def send(client: ActionClient, sequence: str, server_timeout: float, timeout: float, operator: Operator) -> int:
    if not client.wait_for_server(timeout_sec=server_timeout):
        print(f"no sequencer/run server within {server_timeout:g} s", file=sys.stderr)
        return 3
    done = threading.Event()
    goal_future = client.send_goal_async(RunSequence.Goal(sequence=sequence), feedback_callback=operator.print_feedback)
    goal_future.add_done_callback(lambda _: done.set())
    if not done.wait(server_timeout):
        print(f"no goal response from sequencer/run within {server_timeout:g} s", file=sys.stderr)
        return 3
    handle = goal_future.result()
    if not handle.accepted:
        print("goal rejected: another sequence is running (see the sequencer's log)", file=sys.stderr)
        return 1
    done.clear()
    result_future = handle.get_result_async()
    result_future.add_done_callback(lambda _: done.set())
    deadline = time.monotonic() + timeout if timeout > 0 else float("inf")
    try:
        while not done.wait(0.1):
            if time.monotonic() > deadline:
                raise TimeoutError
    except (KeyboardInterrupt, TimeoutError) as reason:
        print("timed out, canceling ..." if isinstance(reason, TimeoutError) else "canceling ...", flush=True)
        handle.cancel_goal_async()
        done.wait()
    operator.wait_for_confirmation()
    response = result_future.result()
    result = response.result
    for name, duration in zip(result.step_names, result.step_durations):
        print(f"  {name:<24} {duration:7.2f} s")
    print(result.message)
    if response.status == GoalStatus.STATUS_CANCELED:
        return 2
    return 0 if result.success else 1


def main(argv=None) -> int:
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.run_sequence", description=__doc__.split("\n")[0])
    parser.add_argument("sequence", help="sequence name: <name>.yaml in the sequencer's sequences_dir (no paths)")
    parser.add_argument("--server-timeout", type=float, default=10.0, help="wait for the sequencer [s]")
    parser.add_argument("--timeout", type=float, default=0.0, help="cancel the sequence after this long [s]; 0 = never")
    args = parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    # No rclpy signal handler: Ctrl-C must reach run() as KeyboardInterrupt to cancel the goal.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    try:
        return run(args.sequence, args.server_timeout, args.timeout)
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
