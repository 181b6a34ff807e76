"""Blocking calls from a plain thread to services and actions of nodes spun elsewhere.

For scripts (the demo, command-line clients): the caller's node is spun by an executor in a background
thread, and these helpers wait on futures without spinning themselves. That executor is a SingleThreadedExecutor:
a client's callbacks only store and print, so one thread serves them, and rclpy 7.1's MultiThreadedExecutor
cost about four times the CPU (the demo's client: 21 s against 5.5 s over one run on an idle 2-core machine,
CPU time sampled from /proc), CPU the stack's own nodes then lacked on a loaded machine.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

import rclpy.action
from action_msgs.msg import GoalStatus


class ActionClient(rclpy.action.ActionClient):
    """rclpy's ActionClient without the lost-response race of ros2/rclpy#1123.

    rclpy 7.1.6 sends a goal, cancel or result request first and registers its future afterwards; an
    executor thread that takes the response in between drops it ("Ignoring unexpected goal response")
    and the future never completes. Sending + registering and taking responses under one lock closes
    that window (the approach of the upstream fix, ros2/rclpy#1308).
    """

    def __init__(self, *args, **kwargs):
        # Before rclpy's __init__, which hands the client to the node's executor: an executor thread may take its
        # data (a latched goal status) at once, and a take that raised left the node's callback group busy for good.
        self._request_lock = threading.RLock()
        super().__init__(*args, **kwargs)

    def take_data(self):
        with self._request_lock:
            return super().take_data()

    def send_goal_async(self, *args, **kwargs):
        with self._request_lock:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, goal_handle):
        with self._request_lock:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle):
        with self._request_lock:
            return super()._get_result_async(goal_handle)


class ClientError(RuntimeError):
    """A service or action did not answer, refused, or did not finish in time."""


def wait_until(predicate: Callable[[], object], timeout: float, what: str, poll_s: float = 0.02):
    """Poll ``predicate`` every ``poll_s`` until it returns something truthy and return it; ClientError on
    timeout."""
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        if time.monotonic() > deadline:
            raise ClientError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(poll_s)
    return value


def _wait_future(future, timeout: float, what: str):
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout):
        raise ClientError(f"timed out after {timeout:g} s waiting for {what}")
    return future.result()


def _wait_for_service(client, timeout: float) -> None:
    if not client.wait_for_service(timeout_sec=timeout):
        raise ClientError(f"service {client.srv_name} did not appear within {timeout:g} s")


def call_service(client, request, timeout: float):
    """Call a service and return its response."""
    _wait_for_service(client, timeout)
    return _wait_future(client.call_async(request), timeout, f"the reply of {client.srv_name}")


def call_repeatable(client, request, timeout: float, resend_s: float):
    """Call a service whose request may safely arrive more than once, sending it again every ``resend_s``
    without a reply; returns the first reply. A reply the server writes before its DDS discovery of this
    client's reply reader has finished is lost for good, and only a new request gets another."""
    _wait_for_service(client, timeout)
    answered, futures = threading.Event(), []
    deadline = time.monotonic() + timeout
    while True:
        future = client.call_async(request)
        future.add_done_callback(lambda _: answered.set())
        futures.append(future)
        remaining = deadline - time.monotonic()
        if answered.wait(max(0.0, min(resend_s, remaining))):
            return next(f.result() for f in futures if f.done())
        if remaining <= resend_s:
            raise ClientError(f"timed out after {timeout:g} s waiting for the reply of {client.srv_name} "
                              f"({len(futures)} requests sent)")


def run_action(client, goal, timeout: float, feedback: Callable | None = None, server_timeout: float = 10.0):
    """Send a goal, wait for its result; returns (GoalStatus code, result message)."""
    name = client._action_name
    if not client.wait_for_server(timeout_sec=server_timeout):
        raise ClientError(f"action server {name} did not appear within {server_timeout:g} s")
    handle = _wait_future(client.send_goal_async(goal, feedback_callback=feedback), server_timeout,
                          f"{name} to accept the goal")
    if not handle.accepted:
        raise ClientError(f"action server {name} rejected the goal")
    response = _wait_future(handle.get_result_async(), timeout, f"the result of {name}")
    return response.status, response.result


def status_name(status: int) -> str:
    names = {GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_ABORTED: "aborted",
             GoalStatus.STATUS_CANCELED: "canceled"}
    return names.get(status, f"status {status}")
