"""The operator's side of an ``operator_swap`` step on ROS: the confirmation service and the estimator's verdict.

``sequencer/operator_done`` (std_srvs/Trigger) confirms the swap the running step asked for; from the command line:
``ros2 service call /sequencer/operator_done std_srvs/srv/Trigger``. It answers success=False when no swap is
awaited. The verdict is the estimator's DiagnosticStatus on ``/diagnostics`` (name ``estimator: <chain>``, values
``assembly``, ``status``, ``mistake``); only a status stamped at or after the confirmation counts, so an image taken
before the swap cannot pass it.
"""
from __future__ import annotations

import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.time import Time
from std_srvs.srv import Trigger

from sequencing.ports import AssemblyVerdict

ESTIMATOR_PREFIX = "estimator: "  # the estimator's DiagnosticStatus names (estimator_node)
CONFIRM_COMMAND = "ros2 service call /sequencer/operator_done std_srvs/srv/Trigger"


def verdict_from_status(status: DiagnosticStatus) -> AssemblyVerdict | None:
    """The estimator's verdict in a DiagnosticStatus; None for another status or one without an assembly."""
    if not status.name.startswith(ESTIMATOR_PREFIX):
        return None
    values = {item.key: item.value for item in status.values}
    if "assembly" not in values:  # refused before any assembly arrived: no verdict on any
        return None
    return AssemblyVerdict(values["assembly"], status.name[len(ESTIMATOR_PREFIX):],
                           status.level == DiagnosticStatus.OK, status.message,
                           tuple(item.value for item in status.values if item.key == "mistake"))


class OperatorRequest:
    """One swap asked of the operator (an engine `OperatorWait`); fed by `OperatorDesk`."""

    def __init__(self, prompt: str):
        self.prompt = prompt
        self._lock = threading.Lock()
        self._confirmed_at: Time | None = None
        self._verdict: AssemblyVerdict | None = None
        self.closed = False

    def confirm(self, now: Time) -> str:
        with self._lock:
            if self._confirmed_at is None:
                self._confirmed_at = now
                return f"confirmed: {self.prompt}; checking the assembly with the camera"
        return f"already confirmed: {self.prompt}"

    def offer(self, stamp: Time, verdict: AssemblyVerdict) -> None:
        with self._lock:
            if self._confirmed_at is not None and stamp >= self._confirmed_at:
                self._verdict = verdict

    def confirmed(self) -> bool:
        with self._lock:
            return self._confirmed_at is not None

    def verdict(self) -> AssemblyVerdict | None:
        with self._lock:
            return self._verdict

    def close(self) -> None:
        self.closed = True


class OperatorDesk:
    """The confirmation service and the verdict subscription of one node; one request open at a time."""

    def __init__(self, node: Node, callback_group):
        self._node = node
        self._request: OperatorRequest | None = None
        node.create_service(Trigger, "sequencer/operator_done", self._on_done, callback_group=callback_group)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10,
                                 callback_group=callback_group)

    def request(self, prompt: str) -> OperatorRequest:
        self._request = OperatorRequest(prompt)
        self._node.get_logger().warning(f"operator: {prompt}; every channel is at 0 V. When done: {CONFIRM_COMMAND}")
        return self._request

    def _open(self) -> OperatorRequest | None:
        request = self._request
        return request if request is not None and not request.closed else None

    def _on_done(self, _request, response):
        pending = self._open()
        if pending is None:
            response.success, response.message = False, "no operator swap is awaited"
        else:
            response.success, response.message = True, pending.confirm(self._node.get_clock().now())
            self._node.get_logger().info(response.message)
        return response

    def _on_diagnostics(self, message: DiagnosticArray) -> None:
        pending = self._open()
        if pending is None:
            return
        for status in message.status:
            verdict = verdict_from_status(status)
            if verdict is not None:
                pending.offer(Time.from_msg(message.header.stamp), verdict)
