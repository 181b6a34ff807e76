"""A fake `Robot` for engine tests: motions finish at once unless told to hang; faults injected on cue (the engine's
n-th reading of the channels, never a thread's timing); `TickingClock`, the engine's time in these tests."""
from __future__ import annotations

import threading
from dataclasses import replace
from collections.abc import Callable

from sequencing.ports import AssemblyVerdict, ChannelReading, Outcome, RobotError

OVER_CURRENT = 1


class TickingClock:
    """Each reading is ``tick`` seconds after the one before: a run's timing depends only on its polls."""

    def __init__(self, tick: float = 1.0):
        self.now, self.tick = 0.0, tick

    def __call__(self) -> float:
        self.now += self.tick
        return self.now


class FakeMotion:
    def __init__(self, outcome: Outcome | None = None):
        self._done = threading.Event()
        self._outcome = outcome
        self.canceled = False
        if outcome is not None:
            self._done.set()

    def wait(self, timeout: float) -> bool:
        return self._done.wait(timeout)

    def outcome(self) -> Outcome:
        return self._outcome

    def finish(self, outcome: Outcome) -> None:
        if not self._done.is_set():
            self._outcome = outcome
            self._done.set()

    def cancel(self) -> None:
        self.canceled = True
        self.finish(Outcome(False, "canceled"))


class FakeOperator:
    """The operator and the camera: confirms on the ``confirm_at``-th poll (None: never), then the estimator
    reports ``verdicts`` one per poll, the last one repeated."""

    def __init__(self, confirm_at: int | None = 1, verdicts: tuple[AssemblyVerdict, ...] = ()):
        self.confirm_at, self.verdicts = confirm_at, list(verdicts)
        self.prompt, self.polls, self.closed = "", 0, False

    def confirmed(self) -> bool:
        self.polls += 1
        return self.confirm_at is not None and self.polls >= self.confirm_at

    def verdict(self) -> AssemblyVerdict | None:
        if not self.verdicts:
            return None
        return self.verdicts.pop(0) if len(self.verdicts) > 1 else self.verdicts[0]

    def close(self) -> None:
        self.closed = True


class FakeRobot:
    """Records every call in ``calls``. ``hook(robot, call)`` may return a motion to use instead of the
    default immediate success (e.g. a hanging FakeMotion) and may inject faults."""

    def __init__(self, channels, hook: Callable | None = None):
        self.states = {channel: ChannelReading(0.0) for channel in channels}
        self.calls: list[tuple] = []
        self.hanging: list[FakeMotion] = []
        self.hook = hook
        self.refuse_ramps = False
        self.operator = FakeOperator(confirm_at=None)
        self.unreachable = False
        self.outputs_active = True  # the driver active: hv_outputs(False) switches every output off
        self.refuse_outputs: str | None = None  # hv_outputs answers this failure
        self._lock = threading.Lock()
        self._on_reading: list[list] = []  # [readings to go, change]

    def after_readings(self, count: int, change: Callable[[FakeRobot], None]) -> None:
        """``change(robot)`` once the engine has read the channels ``count`` more times: a change that comes while
        the engine polls (a voltage that settles, a fault), placed by its polls."""
        self._on_reading.append([count, change])

    def _record(self, call: tuple):
        with self._lock:
            self.calls.append(call)
        return self.hook(self, call) if self.hook else None

    def hang(self) -> FakeMotion:
        motion = FakeMotion()
        self.hanging.append(motion)
        return motion

    def inject_fault(self, channel: str) -> None:
        # Like the driver: a latched fault cuts the output at once.
        self.states[channel] = ChannelReading(0.0, OVER_CURRENT, "OVER_CURRENT", False)

    def move_arm(self, position, orientation, frame_id, speed):
        if self.unreachable:
            raise RobotError("arm/move: action server not available")
        return self._record(("move_arm", tuple(position), frame_id, speed)) or FakeMotion(Outcome(True, "reached"))

    def ramp(self, channel, target, slew_rate):
        motion = self._record(("ramp", channel, target, slew_rate))
        if motion is not None:
            return motion
        if channel not in self.states:
            return FakeMotion(Outcome(False, f"unknown channel {channel!r}"))
        if self.refuse_ramps or self.states[channel].faults:
            return FakeMotion(Outcome(False, "refused: faults latched"))
        if not self.outputs_active:
            return FakeMotion(Outcome(False, "refused: the driver is inactive"))
        self.states[channel] = ChannelReading(target, 0, "", target > 0)
        return FakeMotion(Outcome(True, "", target))

    def pulse(self, channels, voltage, frequency, duty, phase, cycles, edge, slew_rate):
        """Like the driver: the whole train in one command, the channels back at 0 V when it ends."""
        call = ("pulse", tuple(channels), voltage, frequency, duty, phase, cycles, edge, slew_rate)
        motion = self._record(call)
        if motion is not None:
            return motion
        unknown = [channel for channel in channels if channel not in self.states]
        if unknown:
            return FakeMotion(Outcome(False, f"unknown channels {unknown}"))
        if self.refuse_ramps or any(self.states[channel].faults for channel in channels):
            return FakeMotion(Outcome(False, "refused: faults latched"))
        return FakeMotion(Outcome(True, f"completed {cycles} cycles"))

    def pulses(self) -> list[tuple]:
        return [call for call in self.calls if call[0] == "pulse"]

    def channel_states(self):
        for pending in list(self._on_reading):
            pending[0] -= 1
            if pending[0] <= 0:
                self._on_reading.remove(pending)
                pending[1](self)
        return dict(self.states)

    def stop_arm(self):
        self._record(("stop_arm",))

    def estop(self):
        self._record(("estop",))
        return Outcome(True, "e-stop latched")

    def hv_outputs(self, on: bool) -> Outcome:
        self._record(("hv_outputs", on))
        if self.refuse_outputs:
            return Outcome(False, self.refuse_outputs)
        self.outputs_active = on
        for name, state in self.states.items():
            self.states[name] = replace(state, output_enabled=on and not state.faults)
        return Outcome(True, "active" if on else "inactive")

    def request_operator(self, prompt: str) -> FakeOperator:
        self._record(("request_operator", prompt))
        self.operator.prompt = prompt
        return self.operator

    def ramps(self, channel: str | None = None) -> list[tuple]:
        return [call for call in self.calls if call[0] == "ramp" and (channel is None or call[1] == channel)]
