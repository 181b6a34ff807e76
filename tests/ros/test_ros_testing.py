"""The in-process test helpers themselves: an Inbox is never held up by other callbacks of its node."""
import itertools
import threading

import pytest
import rclpy
from ros_testing import Inbox
from waiting import GENEROUS_S
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

pytestmark = pytest.mark.integration


def test_an_inbox_receives_while_another_callback_of_its_node_is_running(ros_context, spin):
    source = rclpy.create_node("number_source", context=ros_context)
    publisher = source.create_publisher(Float64, "numbers", 10)
    counter = itertools.count(1)
    source.create_timer(0.005, lambda: publisher.publish(Float64(data=float(next(counter)))))
    node = rclpy.create_node("inbox_holder", context=ros_context)
    entered, release = threading.Event(), threading.Event()

    def slow_service(_, response):  # holds the node's default callback group, as any slow callback would
        entered.set()
        release.wait(30.0)
        return response

    node.create_service(Trigger, "slow", slow_service)
    spin(source, node)
    slow = source.create_client(Trigger, "slow")
    assert slow.wait_for_service(timeout_sec=GENEROUS_S)
    slow.call_async(Trigger.Request())
    try:
        assert entered.wait(15.0)
        assert Inbox(node, Float64, "numbers").wait(timeout=10.0).data >= 1.0
    finally:
        release.set()
