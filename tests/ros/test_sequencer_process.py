"""The sequencer as its own process, fed crafted sequence files: each goal is answered at once with a short
error, and SIGINT still stops the process cleanly (no freeze in the error path)."""
import signal
import sys

import pytest
import rclpy
from action_msgs.msg import GoalStatus
from crafted_yaml import BILLION_LAUGHS, SELF_REFERENCE
from processes import start, stop
from ros_testing import wait_for
from softblock_interfaces.action import RunSequence

from softblock_ros.client import ActionClient

pytestmark = pytest.mark.integration

NAMESPACE = "/crafted_files"
ANSWER_TIMEOUT = 20.0  # [s] liveness bound; an answer takes milliseconds


@pytest.fixture
def sequencer(tmp_path):
    (tmp_path / "laughs.yaml").write_text(BILLION_LAUGHS)
    (tmp_path / "loop.yaml").write_text(SELF_REFERENCE)
    process = start([sys.executable, "-m", "softblock_ros.sequencer_node", "--ros-args", "-r",
                     f"__ns:={NAMESPACE}", "-p", f"sequences_dir:={tmp_path}"])
    yield process
    stop(process, timeout=10.0)


def test_crafted_files_are_answered_at_once_and_sigint_still_stops_the_node(ros_context, spin, sequencer):
    client = rclpy.create_node("crafted_files_client", context=ros_context)
    action = ActionClient(client, RunSequence, f"{NAMESPACE}/sequencer/run")
    spin(client)
    assert action.wait_for_server(timeout_sec=30.0)
    for name in ("laughs", "loop", "laughs"):
        goal = action.send_goal_async(RunSequence.Goal(sequence=name))
        handle = wait_for(goal.done, ANSWER_TIMEOUT, what=f"the goal response for {name}") and goal.result()
        result = handle.get_result_async()
        wait_for(result.done, ANSWER_TIMEOUT, what=f"the result for {name}")
        assert result.result().status == GoalStatus.STATUS_ABORTED
        message = result.result().result.message
        assert "anchors and aliases" in message and "\n" not in message and len(message) < 300
    assert stop(sequencer, timeout=ANSWER_TIMEOUT, signum=signal.SIGINT) == 0
