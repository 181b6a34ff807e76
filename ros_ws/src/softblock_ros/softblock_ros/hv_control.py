"""Client side of the HV driver's control claim: claim control, send signed heartbeats and goals, release.

Every client that ramps HV channels (the sequencer, the demo, tests, benchmarks) holds control through one
`HvControl`: `claim()` calls hv/claim_control and starts hv/heartbeat; `ramp_goal` / `pulse_goal` make the hv/ramp
and hv/pulse goals; `release()` ends the session (the driver ramps what it left energised to 0 V). The session
token the claim answers never leaves this object: every message carries the session id, a fresh counter and an
HMAC keyed with the token (`hv_driver.control.SessionKey`), so a copy or a recording of it commands nothing.
The calls block on futures without spinning, so the node must be spun by an executor in another thread.
"""
from __future__ import annotations

import secrets

from rclpy.node import Node
from softblock_interfaces.action import PulseChannels, RampChannel
from softblock_interfaces.msg import HvHeartbeat
from softblock_interfaces.srv import ClaimControl, ReleaseControl

from hv_driver.control import HEARTBEAT, RELEASE, SessionKey, pulse_command, ramp_command

from .client import ClientError, call_repeatable, call_service

HEARTBEATS_PER_TIMEOUT = 2  # at least this many heartbeats within the driver's timeout
CLAIM_RESEND_S = 1.0  # a claim without a reply is sent again (the driver answers a repeat with the same session)
NONCE_BYTES = 8
PULSE_EDGES = {"smooth": PulseChannels.Goal.EDGE_SMOOTH, "square": PulseChannels.Goal.EDGE_SQUARE}


def _fields(key: SessionKey, command) -> dict:
    session, counter, mac = key.sign(command)
    return dict(session=session, counter=counter, mac=mac)


class HvControl:
    def __init__(self, node: Node, client: str, heartbeat_rate_hz: float = 10.0, callback_group=None,
                 timeout_s: float = 5.0):
        self.client, self.timeout_s = client, timeout_s
        self._period = 1.0 / heartbeat_rate_hz
        self._claim = node.create_client(ClaimControl, "hv/claim_control", callback_group=callback_group)
        self._release = node.create_client(ReleaseControl, "hv/release_control", callback_group=callback_group)
        self._heartbeat = node.create_publisher(HvHeartbeat, "hv/heartbeat", 10)
        node.create_timer(self._period, self._beat, callback_group=callback_group)
        self._key: SessionKey | None = None  # the live session's key, None without control

    @property
    def session(self) -> str:
        """The live session's public id ("" without control)."""
        key = self._key
        return key.session if key else ""

    def _signed(self, command) -> dict:
        key = self._key
        if key is None:
            raise ClientError(f"{self.client!r} holds no control of the HV driver: claim it first")
        return _fields(key, command)

    def _beat(self) -> None:
        key = self._key
        if key is not None:
            self._heartbeat.publish(HvHeartbeat(**_fields(key, HEARTBEAT)))

    def ramp_goal(self, channel: str, target: float, slew_rate: float = 0.0) -> RampChannel.Goal:
        """An hv/ramp goal signed for the live session (ClientError without control)."""
        return RampChannel.Goal(channel=channel, target=float(target), slew_rate=float(slew_rate),
                                **self._signed(ramp_command(channel, target, slew_rate)))

    def pulse_goal(self, channels, amplitude: float, frequency: float, duty: float, phase: float, cycles: int,
                   edge: str, slew_rate: float = 0.0) -> PulseChannels.Goal:
        """An hv/pulse goal signed for the live session; ``edge`` "smooth" or "square"."""
        command = pulse_command(channels, amplitude, frequency, duty, phase, cycles, edge, slew_rate)
        return PulseChannels.Goal(channels=list(channels), amplitude=float(amplitude), frequency=float(frequency),
                                  duty=float(duty), phase=float(phase), cycles=int(cycles), edge=PULSE_EDGES[edge],
                                  slew_rate=float(slew_rate), **self._signed(command))

    def claim(self) -> str:
        """Take control of the driver; returns the session's public id. ClientError naming the holder when refused."""
        request = ClaimControl.Request(client=self.client, nonce=secrets.token_hex(NONCE_BYTES))
        reply = call_repeatable(self._claim, request, self.timeout_s, CLAIM_RESEND_S)
        if not reply.success:
            raise ClientError(f"hv/claim_control refused: {reply.message}")
        self._key = SessionKey(reply.token)
        if self._key.session != reply.session:
            self._key = None
            raise ClientError(f"hv/claim_control answered session {reply.session!r}, not the one of its token")
        self._beat()
        if self._period * HEARTBEATS_PER_TIMEOUT > reply.heartbeat_timeout:
            self.release()
            raise ClientError(f"heartbeat every {self._period:g} s is too slow for the driver's heartbeat timeout "
                              f"of {reply.heartbeat_timeout:g} s")
        return self._key.session

    def release(self) -> str:
        """End the session (no-op without one); returns the driver's answer."""
        key, self._key = self._key, None
        if key is None:
            return "no control held"
        return call_service(self._release, ReleaseControl.Request(**_fields(key, RELEASE)), self.timeout_s).message
