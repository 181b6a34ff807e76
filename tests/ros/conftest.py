"""Fixtures for in-process ROS tests (helpers in ros_testing.py).

Every test module gets its own rclpy context; nodes under test and the test's client nodes are spun by
a MultiThreadedExecutor in a background thread, so tests talk to them exactly as another process would.

    from ros_testing import call

    def test_x(ros_context, spin):
        node = MyNode(context=ros_context)
        client_node = rclpy.create_node("client", context=ros_context)
        spin(node, client_node)
        reply = call(client_node.create_client(Srv, "name"), Srv.Request())
"""
import pytest
import rclpy
from ros_testing import Spinner


@pytest.fixture(scope="module")
def ros_context():
    """An initialised rclpy context shared by one test module."""
    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture(scope="module")
def spin(ros_context):
    """``spin(*nodes)`` spins nodes in a background executor until the module's tests are done."""
    spinner = Spinner(ros_context)
    yield spinner.add
    spinner.close()
