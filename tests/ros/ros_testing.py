"""Helpers for in-process ROS tests: wait for a condition, call a service, collect messages, spin nodes."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile

from softblock_ros.client import ClientError, call_service, wait_until
from softblock_ros.runner import spin_logging_errors
from waiting import GENEROUS_S

# [s] a deadline for an event, never a measure of its time: at load 18 on two cores a node's start and discovery
# took longer than 15 s
DEFAULT_TIMEOUT = GENEROUS_S
POLL_S = 0.005  # [s] a test's many waits each end this soon after their event


def wait_for(predicate: Callable[[], object], timeout: float = DEFAULT_TIMEOUT, what: str = "condition"):
    """Poll ``predicate`` until it returns something truthy and return that; ClientError on timeout."""
    return wait_until(predicate, timeout, what, POLL_S)


def call(client, request, timeout: float = DEFAULT_TIMEOUT):
    """Call a service from a node that is being spun and return the response."""
    return call_service(client, request, timeout)


class Inbox:
    """A subscription that keeps every message it receives (the node must be spun).

    Each inbox has its own callback group: in the node's default (mutually exclusive) group the executor
    runs one of its callbacks at a time, always the oldest ready entity first, so a few inboxes on busy
    topics would starve a newer inbox and the node's service clients for as long as they keep receiving.
    An inbox is never destroyed while the executor spins: rclpy 7.1 can then fail the executor's wait
    ("cannot use Destroyable because destruction was requested" while it builds its wait set).
    """

    def __init__(self, node: Node, msg_type, topic: str, qos: QoSProfile | int = 10):
        self.topic = topic
        self.messages: list = []
        self._arrived = threading.Condition()
        self._subscription = node.create_subscription(
            msg_type, topic, self._receive, qos, callback_group=MutuallyExclusiveCallbackGroup())

    def _receive(self, message) -> None:
        with self._arrived:
            self.messages.append(message)
            self._arrived.notify_all()

    def wait(self, predicate: Callable[[object], bool] = lambda msg: True, timeout: float = DEFAULT_TIMEOUT):
        """The first message (oldest first, incl. ones already received) that satisfies ``predicate``; looked
        for again as each message arrives."""
        deadline = time.monotonic() + timeout
        with self._arrived:
            while (found := next((msg for msg in list(self.messages) if predicate(msg)), None)) is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    raise ClientError(f"timed out after {timeout:g} s waiting for a matching message on {self.topic}")
                self._arrived.wait(remaining)
        return found


class Spinner:
    """A MultiThreadedExecutor running in a daemon thread; nodes can be added while it spins.

    It spins as the nodes' own processes do (``spin_logging_errors``): an error raised while spinning is
    logged and spinning goes on, so a node under test that destroys entities from a callback (a lifecycle
    cleanup) is not cut off by rclpy's race between that and the executor's wait.
    """

    def __init__(self, context: rclpy.Context, num_threads: int = 4):
        self.executor = MultiThreadedExecutor(num_threads=num_threads, context=context)
        self.nodes: list[Node] = []
        self._closing = threading.Event()
        self._thread = threading.Thread(target=spin_logging_errors, daemon=True, args=(
            self.executor, rclpy.logging.get_logger("test_spinner"), lambda: not self._closing.is_set()))
        self._thread.start()

    def add(self, *nodes: Node) -> None:
        for node in nodes:
            self.executor.add_node(node)
            self.nodes.append(node)

    def close(self) -> None:
        """Stop spinning and destroy the nodes (once: a second call does nothing)."""
        if self._closing.is_set():
            return
        self._closing.set()
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        for node in reversed(self.nodes):
            node.destroy_node()
