"""`run_sequence` confirms an operator_swap step from its own terminal: the wheel set-up has no ros2 CLI for
`ros2 service call /sequencer/operator_done ...`, so Enter typed into run_sequence while the step waits is the
confirmation; a line typed while nothing waits confirms nothing."""
import subprocess
import sys
import threading
import time

import pytest
import rclpy
from rclpy.action import ActionServer
from rclpy.callback_groups import ReentrantCallbackGroup
from softblock_interfaces.action import RunSequence
from std_srvs.srv import Trigger

from processes import start, stop

from softblock_ros.run_sequence import Operator

pytestmark = pytest.mark.integration

TIMEOUT = 120.0  # [s] liveness bound only
REPLY_DELAY_S = 0.5  # [s] after the sequence's end: the stand-in answers a confirmation only then
PROMPT = "build assembly 'asymmetric_gripper': finger front_left, position 2: remove design 57, insert design 15"


@pytest.fixture
def sequencer(ros_context, spin):
    """A stand-in sequencer: its one step asks the operator and succeeds once sequencer/operator_done is called.
    Its reply to the confirmation leaves after the sequence has ended: the order a loaded sequencer may answer in
    (seen: run_sequence printed the result and exited before the reply came, and the reply was never printed)."""
    node = rclpy.create_node("sequencer", context=ros_context)
    group, confirmed, finished, confirmations = ReentrantCallbackGroup(), threading.Event(), threading.Event(), []

    def operator_done(request, response):
        confirmations.append(confirmed.is_set())
        response.success, response.message = not confirmed.is_set(), "swap confirmed; waiting for the camera"
        confirmed.set()
        finished.wait(TIMEOUT)
        time.sleep(REPLY_DELAY_S)
        return response

    def execute(goal):
        goal.publish_feedback(RunSequence.Feedback(step_index=0, step_count=1, step_name="swap",
                                                   description=PROMPT, phase="awaiting_operator"))
        confirmed.wait(TIMEOUT)
        goal.succeed()
        finished.set()
        return RunSequence.Result(success=confirmed.is_set(), message="the swap was verified",
                                  step_names=["swap"], step_durations=[1.0])

    node.create_service(Trigger, "sequencer/operator_done", operator_done, callback_group=group)
    node.server = ActionServer(node, RunSequence, "sequencer/run", execute, callback_group=group)
    spin(node)
    return confirmations


def test_enter_typed_into_run_sequence_confirms_the_awaited_swap(sequencer):
    run = start([sys.executable, "-m", "softblock_ros.run_sequence", "swap_demo", "--server-timeout", "60"],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        while not lines or "press Enter" not in lines[-1]:
            lines.append(run.stdout.readline())
            assert lines[-1], "run_sequence ended before asking the operator: " + "".join(lines)
        assert f"operator: {PROMPT}\n" in lines
        run.stdin.write("\n")
        run.stdin.flush()
        out, err = run.communicate(timeout=TIMEOUT)
    finally:
        stop(run, TIMEOUT)
    assert run.returncode == 0, out + err
    reply, result = out.find("operator: swap confirmed; waiting for the camera"), out.find("the swap was verified")
    assert 0 <= reply < result, out  # the reply, then the result
    assert sequencer == [False]  # confirmed once


def test_a_line_typed_while_no_swap_waits_confirms_nothing(ros_context, capsys):
    node = rclpy.create_node("operator_probe", context=ros_context)
    try:
        Operator(node, keyboard=iter(["\n"])).listen()  # returns at the end of input
    finally:
        node.destroy_node()
    assert capsys.readouterr().out == "operator: no swap is asked for now\n"


def test_without_a_readable_terminal_the_operator_is_told_to_confirm_through_the_service(ros_context, capsys):
    """Standard input that cannot be read (pytest's capture, a closed stdin) ends the listener quietly, and the
    prompt then names the service instead of Enter (it raised out of the listener's thread)."""
    class Unreadable:
        def __iter__(self):
            raise OSError("reading from stdin while output is captured")

    node = rclpy.create_node("operator_probe", context=ros_context)
    try:
        operator = Operator(node, keyboard=Unreadable())
        operator.listen()
        feedback = RunSequence.Feedback(step_index=0, step_count=1, step_name="swap", description=PROMPT,
                                        phase="awaiting_operator")
        operator.print_feedback(RunSequence.Impl.FeedbackMessage(feedback=feedback))
    finally:
        node.destroy_node()
    assert "call the service sequencer/operator_done to confirm" in capsys.readouterr().out
