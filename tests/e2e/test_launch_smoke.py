"""Each node of the shipped stack, launched alone as the launcher starts it (its stack files, its niceness, a
namespace of its own), comes up, serves its parameters and stops cleanly on Ctrl-C. The nodes start at once, so
that their start-ups overlap; each test stops its own. What the nodes do is tested in-process (tests/ros)."""
import io
import time

import pytest
import rclpy
from rcl_interfaces.srv import GetParameters
from rclpy.executors import SingleThreadedExecutor

from softblock_ros.client import wait_until
from softblock_ros.launcher import Stack
from softblock_ros.stack import load_stack

# stack: `make test` runs it after the other tiers, beside another stack module (tests/conftest.py)
pytestmark = pytest.mark.stack

START_TIMEOUT = 120.0  # [s] liveness bound only: the planner prepares its search at niceness 10 on a loaded host
RESEND_S = 2.0  # [s] a request without a reply is sent again after this
# [s] liveness bound only: a clean stop is the node ending on SIGINT with status 0, however long a loaded host takes
# (the planner, at niceness 10 beside two busy loops, took over 10 s, the launcher's default, to end)
STOP_TIMEOUT = 60.0


@pytest.fixture(scope="module")
def client():
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("launch_smoke_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def ask_until_answered(executor, service, request):
    """The reply to ``request``, sent again every RESEND_S without one (None after START_TIMEOUT): a reply the node
    writes before its discovery of this client's reply reader is lost for good ("failed to send response")."""
    deadline, futures = time.monotonic() + START_TIMEOUT, []
    while time.monotonic() < deadline:
        futures.append(service.call_async(request))
        executor.spin_until_future_complete(futures[-1], timeout_sec=RESEND_S)
        answered = next((f for f in futures if f.done()), None)
        if answered is not None:
            return answered.result()
    return None


@pytest.fixture(scope="module")
def launched(tmp_path_factory):
    """Every node of the stack, each launched alone in a namespace of its own, all at once (their start-ups
    overlap): name -> (its Stack, its output)."""
    params = tmp_path_factory.mktemp("smoke") / "params.yaml"  # nothing written into the work tree
    # the live view on a free port: its default, 8765, may be another suite's or a user's on this machine
    params.write_text(f"/**/recorder:\n  ros__parameters:\n    output: {params.parent / 'recording.mcap'}\n"
                      "/**/foxglove_bridge:\n  ros__parameters:\n    port: 0\n")
    stacks = {}
    try:
        for name in load_stack().names:
            output = io.StringIO()
            stacks[name] = Stack(nodes=[name], params=params, output=output, namespace=f"/smoke_{name}",
                                 stop_timeout=STOP_TIMEOUT).start(), output
        yield stacks
    finally:
        for stack, _ in stacks.values():
            stack.stop()


@pytest.mark.parametrize("name", load_stack().names)
def test_the_node_starts_alone_serves_its_parameters_and_stops_cleanly(client, launched, name):
    node, executor = client
    stack, output = launched[name]
    parameters = node.create_client(GetParameters, f"/smoke_{name}/{name}/get_parameters")
    wait_until(lambda: parameters.wait_for_service(timeout_sec=1.0) or stack.dead(), START_TIMEOUT,
               f"{name}'s parameter service")
    assert stack.dead() == {}, output.getvalue()[-3000:]
    # a node's services answer once it is built and spun: the node is up, not only its process
    reply = ask_until_answered(executor, parameters, GetParameters.Request(names=["use_sim_time"]))
    assert reply is not None, f"{name} did not answer get_parameters\n" + output.getvalue()[-3000:]
    assert reply.values[0].bool_value is False
    assert stack.stop() == {name: 0}, output.getvalue()[-3000:]
    assert "Traceback" not in output.getvalue(), output.getvalue()[-3000:]
