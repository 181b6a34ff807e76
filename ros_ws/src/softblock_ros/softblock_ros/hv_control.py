"""Client side of the HV driver's control claim: claim control, send heartbeats with the session token, release.

Every client that ramps HV channels (the sequencer, the demo, tests, benchmarks) holds control through one
`HvControl`: `claim()` calls hv/claim_control and starts hv/heartbeat with the token it answers; `token`
goes into every hv/ramp goal; `release()` ends the session (the driver ramps what it left energised to 0 V).
The calls block on futures without spinning, so the node must be spun by an executor in another thread.
"""
from __future__ import annotations

from rclpy.node import Node
from softblock_interfaces.msg import HvHeartbeat
from softblock_interfaces.srv import ClaimControl, ReleaseControl

from .client import ClientError, call_repeatable, call_service

HEARTBEATS_PER_TIMEOUT = 2  # at least this many heartbeats within the driver's timeout
CLAIM_RESEND_S = 1.0  # a claim without a reply is sent again (the driver answers a repeat with the same session)


class HvControl:
    def __init__(self, node: Node, client: str, heartbeat_rate_hz: float = 10.0, callback_group=None,
                 timeout_s: float = 5.0):
        self.client, self.timeout_s = client, timeout_s
        self._period = 1.0 / heartbeat_rate_hz
        self._claim = node.create_client(ClaimControl, "hv/claim_control", callback_group=callback_group)
        self._release = node.create_client(ReleaseControl, "hv/release_control", callback_group=callback_group)
        self._heartbeat = node.create_publisher(HvHeartbeat, "hv/heartbeat", 10)
        node.create_timer(self._period, self._beat, callback_group=callback_group)
        self.token = ""  # the live session's token, "" without control

    def _beat(self) -> None:
        token = self.token
        if token:
            self._heartbeat.publish(HvHeartbeat(token=token))

    def claim(self) -> str:
        """Take control of the driver; ClientError naming the holder when it is refused."""
        reply = call_repeatable(self._claim, ClaimControl.Request(client=self.client), self.timeout_s,
                                CLAIM_RESEND_S)
        if not reply.success:
            raise ClientError(f"hv/claim_control refused: {reply.message}")
        self.token = reply.token
        self._beat()
        if self._period * HEARTBEATS_PER_TIMEOUT > reply.heartbeat_timeout:
            self.release()
            raise ClientError(f"heartbeat every {self._period:g} s is too slow for the driver's heartbeat timeout "
                              f"of {reply.heartbeat_timeout:g} s")
        return self.token

    def release(self) -> str:
        """End the session (no-op without one); returns the driver's answer."""
        token, self.token = self.token, ""
        if not token:
            return "no control held"
        return call_service(self._release, ReleaseControl.Request(token=token), self.timeout_s).message
