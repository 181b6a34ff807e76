"""The sequencer's operator_swap step through real rclpy clients: the operator confirms on
sequencer/operator_done, the estimator's verdict arrives on /diagnostics; a mismatch ends the sequence naming the
block before any channel is energised, a match lets it go on."""
import pytest
import rclpy
import yaml
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from fake_hv import FakeHv
from rclpy.parameter import Parameter
from ros_testing import Inbox, call, wait_for
from waiting import GENEROUS_S
from softblock_interfaces.action import RunSequence
from softblock_interfaces.msg import SequenceEvent
from std_srvs.srv import Trigger

from softblock_ros.client import ActionClient
from softblock_ros.sequencer_node import SequencerNode

pytestmark = pytest.mark.integration

NAMESPACE = "/operator_swap"
TARGET = "asymmetric_gripper"
SEQUENCE = {"name": "reconfigure", "channels": ["front"], "steps": [
    {"name": "swap", "operator_swap": {"assembly": TARGET, "swaps": [
        {"chain": "front_left", "position": 2, "remove": 57, "insert": 15, "rotation_steps": 0}]}},
    {"name": "close", "ramp": {"channel": "front", "target": 2000}}]}


@pytest.fixture(scope="module")
def stack(ros_context, spin, tmp_path_factory):
    directory = tmp_path_factory.mktemp("sequences")
    (directory / "reconfigure.yaml").write_text(yaml.safe_dump(SEQUENCE))
    sequencer = SequencerNode(context=ros_context, namespace=NAMESPACE, parameter_overrides=[
        Parameter("sequences_dir", value=str(directory)), Parameter("settle_time_s", value=2.0),
        Parameter("safe_stop_timeout_s", value=5.0)])
    hv = FakeHv(["front"], context=ros_context, namespace=NAMESPACE)
    client = rclpy.create_node("operator", context=ros_context, namespace=NAMESPACE)
    stack = {"hv": hv, "client": client, "action": ActionClient(client, RunSequence, "sequencer/run"),
             "done": client.create_client(Trigger, "sequencer/operator_done"),
             "diagnostics": client.create_publisher(DiagnosticArray, "/diagnostics", 10),
             "events": Inbox(client, SequenceEvent, "sequencer/events", 100)}
    spin(sequencer, hv, client)
    assert stack["action"].wait_for_server(timeout_sec=GENEROUS_S)
    return stack


def estimator_status(level, message, mistakes=()) -> DiagnosticStatus:
    values = [KeyValue(key="assembly", value=TARGET), KeyValue(key="status", value=message)]
    return DiagnosticStatus(level=level, name="estimator: front_left", message=message,
                            values=values + [KeyValue(key="mistake", value=m) for m in mistakes])


def swap_and_see(stack, status: DiagnosticStatus):
    """Run the sequence; once the swap is awaited confirm it, then publish the camera's verdict until it ends."""
    stack["hv"].reset()
    stack["events"].messages.clear()
    future = stack["action"].send_goal_async(RunSequence.Goal(sequence="reconfigure"))
    wait_for(future.done, what="the goal response")
    handle = future.result()
    assert handle.accepted
    stack["events"].wait(lambda msg: (msg.step_name, msg.phase) == ("swap", "awaiting_operator"))
    stack["was_inactive"] = not stack["hv"].active  # switched off before the operator is asked
    reply = call(stack["done"], Trigger.Request())
    assert reply.success and "confirmed: build assembly 'asymmetric_gripper'" in reply.message, reply.message
    result = handle.get_result_async()

    def verdict_sent_and_done() -> bool:
        stamp = stack["client"].get_clock().now().to_msg()  # an image taken after the confirmation
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = stamp
        stack["diagnostics"].publish(msg)
        return result.done()

    wait_for(verdict_sent_and_done, 30.0, what="the sequence result")
    assert stack["was_inactive"], "the HV driver was not deactivated for the swap"
    return result.result().status, result.result().result


def test_no_swap_awaited_is_refused(stack):
    reply = call(stack["done"], Trigger.Request())
    assert not reply.success and reply.message == "no operator swap is awaited"


def test_a_mismatch_names_the_block_before_any_channel_is_energised(stack):
    mistake = "block 3: design 57 instead of 15 (candidates [57])"
    status, result = swap_and_see(stack, estimator_status(DiagnosticStatus.WARN, "assembly mistakes found",
                                                           [mistake]))
    assert status == GoalStatus.STATUS_ABORTED and result.failed_step == "swap"
    assert f"assembly 'asymmetric_gripper' not as built: chain front_left: {mistake}" in result.message
    assert stack["hv"].ramps == [] and not stack["hv"].active


def test_a_match_lets_the_sequence_energise_again(stack):
    status, result = swap_and_see(stack, estimator_status(DiagnosticStatus.OK, "as built"))
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    assert stack["hv"].ramps == [("front", 2000.0)] and stack["hv"].active
