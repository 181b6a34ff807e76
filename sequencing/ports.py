"""The engine's ports: what it drives (`Robot`, `Motion`), what those report (`Outcome`, `ChannelReading`)
and how it runs (`RunOptions`). A backend (the ROS adapter, a test fake) implements `Robot`; nothing here runs.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True)
class Outcome:
    """End of a motion or command; ``value`` carries e.g. the final measured voltage of a ramp."""

    success: bool
    message: str = ""
    value: float | None = None


@dataclass(frozen=True)
class ChannelReading:
    """Latest state of one HV channel."""

    voltage: float             # measured [V]
    faults: int = 0            # latched fault bits (0 = none)
    fault_text: str = ""
    output_enabled: bool = False
    stale: bool = False        # the backend has not heard from the driver in time: the output's true state is unknown


class Motion(Protocol):
    """A running arm move, channel ramp or pulse train."""

    def wait(self, timeout: float) -> bool:
        """Block up to ``timeout`` seconds; True once the motion has finished."""

    def outcome(self) -> Outcome:
        """How it ended (only after ``wait`` returned True)."""

    def cancel(self) -> None:
        """Ask the backend to stop it (an arm brakes, a channel ramps to 0 V)."""


@dataclass(frozen=True)
class AssemblyVerdict:
    """The camera estimator's verdict on one image: did the chain it saw match the assembly it believes?"""

    assembly: str                # the assembly the image was compared with
    chain: str                   # the chain the camera sees
    as_built: bool
    message: str = ""
    mistakes: tuple[str, ...] = ()  # each names the block (position, designs), e.g. "block 3: design 57 instead of 15"


class OperatorWait(Protocol):
    """A pending request to the operator (a block swap): their confirmation, then the estimator's verdict."""

    def confirmed(self) -> bool:
        """True once the operator confirmed the swap."""

    def verdict(self) -> AssemblyVerdict | None:
        """The estimator's newest verdict on an image taken after the confirmation (None: none yet)."""

    def close(self) -> None:
        """No more confirmations are taken for this request."""


class Robot(Protocol):
    """What the engine drives. Methods raise `RobotError` when the backend cannot be reached."""

    def move_arm(self, position, orientation, frame_id: str, speed: float) -> Motion: ...

    def ramp(self, channel: str, target: float, slew_rate: float) -> Motion: ...

    def pulse(self, channels: Sequence[str], voltage: float, frequency: float, duty: float, phase: float,
              cycles: int, edge: str, slew_rate: float) -> Motion:
        """A periodic train on ``channels`` run by the HV driver (``edge`` "smooth" or "square"); its outcome
        says how it ran."""

    def channel_states(self) -> Mapping[str, ChannelReading]: ...

    def stop_arm(self) -> None: ...

    def estop(self) -> Outcome: ...

    def request_operator(self, prompt: str) -> OperatorWait:
        """Show ``prompt`` to the operator and take their confirmation from now on."""

    def hv_outputs(self, on: bool) -> Outcome:
        """False: every output of the HV driver ramped to 0 V and switched off, and ramps refused, until True
        switches them on again at 0 V (the driver node's lifecycle: inactive, active)."""


class RobotError(RuntimeError):
    """The backend could not take a command (server missing, goal refused)."""


@dataclass(frozen=True)
class RunOptions:
    poll_period_s: float = 0.02        # how often faults, cancel and timeouts are checked
    settle_time_s: float = 1.0         # how long a precondition may take to become true
    safe_stop_timeout_s: float = 15.0  # for the ramp-down of every channel
    off_voltage_v: float = 20.0        # a disabled output below this needs no ramp-down
