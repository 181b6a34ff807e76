"""softblock_ros.client: the blocking helpers' action client."""
import pytest
import rclpy
import rclpy.action
from softblock_interfaces.action import MoveArm

from softblock_ros.client import ActionClient

pytestmark = pytest.mark.integration


def test_an_action_client_can_be_taken_from_as_soon_as_its_node_holds_it(ros_context, monkeypatch):
    """Seen in a stress run (test_planner_actions.py): a new action client on a node spun in the background was taken
    from by the executor before its lock existed; the take raised AttributeError, which left the node's default
    callback group marked as running, so no later goal of that node was ever answered (four tests timed out). Here
    the take comes at the earliest moment an executor thread can make it: when the node adds the client (rclpy's
    own take, which needs a wait first, stands aside: what is tested is the client's wrapper around it)."""
    taken = []
    monkeypatch.setattr(rclpy.action.ActionClient, "take_data", lambda client: taken.append(client) or {})
    node = rclpy.create_node("early_take", context=ros_context)
    add_waitable = node.add_waitable

    def add_then_take(waitable):
        add_waitable(waitable)
        waitable.take_data()

    node.add_waitable = add_then_take
    try:
        client = ActionClient(node, MoveArm, "arm/move")
        assert taken == [client]
    finally:
        node.destroy_node()
