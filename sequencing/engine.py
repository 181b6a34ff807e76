"""Backend-agnostic executor of validated sequences (no ROS).

The engine runs steps against a `Robot`: an arm that moves to poses, HV channels that ramp, and a
view of the channel states. The ROS sequencer node adapts its action clients to this interface;
tests use a fake. Every step:

1. precondition: no HV fault on the sequence's channels and the expected channel voltages within
   tolerance (re-checked for up to ``settle_time_s``, since the state arrives a little after a ramp);
2. running: motions are watched until done; a cancel, the step's timeout or an HV fault cancels them;
3. a ramp must end with the measured voltage within tolerance of its target (allowed ``settle_time_s``).

An ``operator_swap`` step needs every channel at 0 V, asks the operator for the swaps, waits for their
confirmation and then for the camera estimator to find the new assembly as built; a channel energised
meanwhile, a mismatch (the message names the block) or the timeout fail it.

On failure the step's ``on_failure`` reaction runs (``safe_stop``: arm stops, every channel ramps to
0 V, e-stop if a ramp-down fails; ``estop``: arm stops, e-stop at once). A cancel always does the
safe stop. Blocking calls run in the caller's thread; parallel steps use one thread per branch.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from hv_driver.ramp import MIN_JERK_PEAK_RATE

from .ports import Motion, Outcome, Robot, RobotError, RunOptions
from .schema import (MoveArmStep, OperatorSwapStep, ParallelStep, PulseTrainStep, RampStep, Sequence, Step,
                     WaitStep)


@dataclass(frozen=True)
class StepEvent:
    sequence: str
    index: int        # top-level step index
    count: int
    name: str
    description: str
    phase: str        # "precondition", "running", "awaiting_operator", "succeeded", "failed", "canceled"
    message: str = ""


@dataclass(frozen=True)
class RunResult:
    success: bool
    message: str
    canceled: bool = False
    failed_step: str = ""
    step_names: list[str] = field(default_factory=list)
    step_durations: list[float] = field(default_factory=list)  # [s]


class StepFailure(Exception):
    """A step did not succeed; carries the reaction of the step that failed."""

    def __init__(self, message: str, on_failure: str | None = None):
        super().__init__(message)
        self.on_failure = on_failure  # None until the step that failed fills in its own


class _Halted(StepFailure):
    """A parallel branch stopped because a sibling failed (the sibling's failure is reported)."""


class SequenceCanceled(Exception):
    pass


@dataclass(frozen=True)
class _Context:
    sequence: Sequence
    cancel: threading.Event
    halt: threading.Event  # set when a parallel sibling failed
    deadline: float
    timeout: float
    emit: Callable[..., None]  # emit(phase, message=""): a StepEvent of the top-level step


class SequenceEngine:
    def __init__(self, robot: Robot, options: RunOptions = RunOptions(),
                 on_event: Callable[[StepEvent], None] = lambda event: None, clock=time.monotonic):
        self.robot, self.options, self.on_event, self.clock = robot, options, on_event, clock

    def run(self, sequence: Sequence, cancel: threading.Event | None = None) -> RunResult:
        """Run every step in order; returns when done, after a failure's reaction or after a cancel."""
        cancel = cancel or threading.Event()
        names, durations = [], []
        count = sequence.step_count()
        for index, step in enumerate(sequence.steps):
            def emit(phase: str, message: str = ""):
                self.on_event(StepEvent(sequence.name, index, count, step.name, step.description, phase, message))

            started = self.clock()
            names.append(step.name)
            try:
                ctx = _Context(sequence, cancel, threading.Event(), started + step.timeout, step.timeout, emit)
                emit("precondition")
                self._check_precondition(step, ctx)
                emit("running")
                message = self._execute(step, ctx)
                self._raise_on_fault(sequence)  # a fault latched as the step ended still fails it
                durations.append(self.clock() - started)
                emit("succeeded", message)
            except SequenceCanceled:
                durations.append(self.clock() - started)
                reaction = self._safe_stop(sequence)
                emit("canceled", reaction)
                return RunResult(False, f"canceled during step {step.name!r}; {reaction}", True, step.name,
                                 names, durations)
            except StepFailure as failure:
                durations.append(self.clock() - started)
                reaction = self._react(failure.on_failure or step.on_failure, sequence)
                emit("failed", f"{failure}; {reaction}")
                return RunResult(False, f"step {step.name!r} failed: {failure}; {reaction}", False, step.name,
                                 names, durations)
            except Exception:
                self._safe_stop(sequence)  # an unexpected error still leaves the robot safe
                raise
        return RunResult(True, f"sequence {sequence.name!r}: all {count} steps succeeded", False, "",
                         names, durations)

    # -- checks ---------------------------------------------------------------------------------------

    def _faults(self, sequence: Sequence) -> list[str]:
        states = self.robot.channel_states()
        return [f"{channel}: {states[channel].fault_text or hex(states[channel].faults)}"
                for channel in sequence.channels if channel in states and states[channel].faults]

    def _raise_on_fault(self, sequence: Sequence) -> None:
        faults = self._faults(sequence)
        if faults:
            raise StepFailure(f"HV fault ({'; '.join(faults)})")

    def _check_interrupts(self, ctx: _Context) -> None:
        if ctx.cancel.is_set():
            raise SequenceCanceled()
        if ctx.halt.is_set():
            raise _Halted("stopped because a parallel step failed")
        self._raise_on_fault(ctx.sequence)
        if self.clock() > ctx.deadline:
            raise StepFailure(f"timed out after {ctx.timeout:g} s")

    def _precondition_problems(self, step: Step, sequence: Sequence) -> list[str]:
        states = self.robot.channel_states()
        problems = [f"channel {channel!r} not reported by the HV driver"
                    for channel in sequence.channels if channel not in states]
        tolerance = step.precondition.tolerance
        for channel, expected in step.precondition.voltages.items():
            if channel in states and abs(states[channel].voltage - expected) > tolerance:
                problems.append(f"channel {channel!r} at {states[channel].voltage:.0f} V, "
                                f"expected {expected:.0f} +- {tolerance:.0f} V")
        if isinstance(step, OperatorSwapStep):  # outputs on at 0 V are fine: the step switches them off
            problems += [f"{problem}; an operator swap needs every channel at 0 V"
                         for problem in self._energised(sequence, outputs_count=False)]
        return problems

    def _energised(self, sequence: Sequence, outputs_count: bool = True) -> list[str]:
        """Channels that are (or may be) live: above the off voltage, state unknown, or (``outputs_count``)
        output on."""
        states, off = self.robot.channel_states(), self.options.off_voltage_v
        return [f"channel {channel!r} " + ("state unknown" if states[channel].stale else
                                           f"energised ({states[channel].voltage:.0f} V)")
                for channel in sequence.channels if channel in states
                and (states[channel].stale or (outputs_count and states[channel].output_enabled)
                     or abs(states[channel].voltage) > off)]

    def _check_precondition(self, step: Step, ctx: _Context) -> None:
        settle_until = self.clock() + self.options.settle_time_s
        while True:
            faults = self._faults(ctx.sequence)
            if faults:
                raise StepFailure(f"precondition: HV fault latched ({'; '.join(faults)}); reset faults first",
                                  step.on_failure)
            problems = self._precondition_problems(step, ctx.sequence)
            if not problems:
                return
            if self.clock() > settle_until:
                raise StepFailure(f"precondition: {'; '.join(problems)}", step.on_failure)
            if ctx.cancel.wait(self.options.poll_period_s):
                raise SequenceCanceled()

    # -- waiting ----------------------------------------------------------------------------------------

    def _watch(self, motions: list[Motion], ctx: _Context) -> list[Outcome]:
        """Wait for every motion; cancel them all on cancel, timeout, HV fault or a failed sibling."""
        try:
            while True:
                pending = [motion for motion in motions if not motion.wait(0.0)]
                if not pending:
                    return [motion.outcome() for motion in motions]
                self._check_interrupts(ctx)
                pending[0].wait(self.options.poll_period_s)
        except (SequenceCanceled, StepFailure):
            for motion in motions:
                motion.cancel()
            raise

    def _sleep_until(self, when: float, ctx: _Context) -> None:
        while (remaining := when - self.clock()) > 0:
            self._check_interrupts(ctx)
            ctx.cancel.wait(min(remaining, self.options.poll_period_s))
        self._check_interrupts(ctx)

    # -- step kinds -------------------------------------------------------------------------------------

    def _execute(self, step: Step, ctx: _Context) -> str:
        try:
            if isinstance(step, MoveArmStep):
                return self._move_arm(step, ctx)
            if isinstance(step, RampStep):
                return self._ramp(step, ctx)
            if isinstance(step, WaitStep):
                self._sleep_until(self.clock() + step.duration, ctx)
                return f"waited {step.duration:g} s"
            if isinstance(step, ParallelStep):
                return self._parallel(step, ctx)
            if isinstance(step, PulseTrainStep):
                return self._pulse_train(step, ctx)
            if isinstance(step, OperatorSwapStep):
                return self._operator_swap(step, ctx)
            raise TypeError(f"unknown step type {type(step).__name__}")
        except RobotError as error:
            raise StepFailure(str(error), step.on_failure) from error
        except StepFailure as failure:
            failure.on_failure = failure.on_failure or step.on_failure
            raise

    def _move_arm(self, step: MoveArmStep, ctx: _Context) -> str:
        motion = self.robot.move_arm(step.position, step.orientation, step.frame_id, step.speed)
        outcome, = self._watch([motion], ctx)
        if not outcome.success:
            raise StepFailure(f"arm move failed: {outcome.message}")
        return outcome.message or "arm reached the target"

    def _check_reached(self, channel: str, target: float, tolerance: float, outcome: Outcome, ctx: _Context) -> None:
        """The ramp succeeded and the measured voltage settled within tolerance (it lags the setpoint a little)."""
        if not outcome.success:
            raise StepFailure(f"ramp of {channel!r} to {target:.0f} V failed: {outcome.message}")
        voltage, settle_until = outcome.value, self.clock() + self.options.settle_time_s
        while voltage is None or abs(voltage - target) > tolerance:
            if self.clock() > settle_until:
                raise StepFailure(f"channel {channel!r} ended at {voltage:.0f} V, expected {target:.0f} "
                                  f"+- {tolerance:.0f} V")
            self._check_interrupts(ctx)
            ctx.cancel.wait(self.options.poll_period_s)
            voltage = self.robot.channel_states()[channel].voltage

    def _ramp(self, step: RampStep, ctx: _Context) -> str:
        slew_rate = step.slew_rate
        if step.duration is not None:
            # The driver's minimum-jerk ramp lasts MIN_JERK_PEAK_RATE * |dV| / slew_rate.
            present = self.robot.channel_states()[step.channel].voltage
            slew_rate = MIN_JERK_PEAK_RATE * abs(step.target - present) / step.duration
        outcome, = self._watch([self.robot.ramp(step.channel, step.target, slew_rate)], ctx)
        self._check_reached(step.channel, step.target, step.tolerance, outcome, ctx)
        return f"{step.channel} at {step.target:.0f} V"

    def _parallel(self, step: ParallelStep, ctx: _Context) -> str:
        halt, lock = threading.Event(), threading.Lock()
        errors: list[BaseException] = []

        def branch(child: Step) -> str:
            child_ctx = _Context(ctx.sequence, ctx.cancel, halt, min(ctx.deadline, self.clock() + child.timeout),
                                 child.timeout, ctx.emit)
            try:
                self._check_precondition(child, child_ctx)
                return self._execute(child, child_ctx)
            except (SequenceCanceled, StepFailure) as error:
                with lock:
                    errors.append(error)
                halt.set()
                raise

        with ThreadPoolExecutor(max_workers=len(step.steps), thread_name_prefix=f"step-{step.name}") as pool:
            futures = [(child, pool.submit(branch, child)) for child in step.steps]
        if any(isinstance(error, SequenceCanceled) for error in errors):
            raise SequenceCanceled()
        first = next((error for error in errors if not isinstance(error, _Halted)), errors[0] if errors else None)
        if first is not None:
            failed = next(child for child, future in futures if future.exception() is first)
            raise StepFailure(f"{failed.name}: {first}", first.on_failure)
        return "; ".join(f"{child.name}: {future.result()}" for child, future in futures)

    def _pulse_train(self, step: PulseTrainStep, ctx: _Context) -> str:
        """One periodic command for all the step's channels: the HV driver switches them itself (on the supply
        where it switches by itself, else in its control loop), never one action round trip per edge. Cancel,
        a fault or the timeout cancel it (the channels go back to 0 V); at its end every channel is checked back
        at 0 V."""
        train = self.robot.pulse(step.channels, step.voltage, step.frequency, step.duty, step.phase, step.cycles,
                                 step.edge, step.slew_rate)
        outcome, = self._watch([train], ctx)
        if not outcome.success:
            raise StepFailure(f"pulse train on {list(step.channels)} failed: {outcome.message}")
        for channel in step.channels:
            self._check_reached(channel, 0.0, step.tolerance, Outcome(True), ctx)
        return f"{step.cycles} cycles on {list(step.channels)} at {step.frequency:g} Hz ({outcome.message})"

    def _operator_swap(self, step: OperatorSwapStep, ctx: _Context) -> str:
        """The HV outputs off (hands near the electrodes), then the confirmation, then a verdict on the new
        assembly from an image taken after it; meanwhile every channel must stay off at 0 V. A verdict on another
        assembly (the estimator has not got the new one yet) is waited past. Only an as-built verdict switches
        the outputs on again: after a mistake they stay off."""
        self._outputs_off(ctx)
        request = self.robot.request_operator(step.prompt())
        ctx.emit("awaiting_operator", step.prompt())  # only now can a confirmation be taken
        waiting_for, verdict = "the operator's confirmation", None
        try:
            while True:
                if self.clock() > ctx.deadline:
                    seen = f"; last verdict: {verdict.message} on assembly {verdict.assembly!r}" if verdict else ""
                    raise StepFailure(f"timed out after {ctx.timeout:g} s waiting for {waiting_for}{seen}")
                self._check_interrupts(ctx)
                energised = self._energised(ctx.sequence)
                if energised:
                    raise StepFailure(f"{'; '.join(energised)} during the operator's swap")
                if request.confirmed():
                    waiting_for = f"the estimator's verdict on assembly {step.assembly!r}"
                    verdict = request.verdict()
                    if verdict is not None and verdict.assembly == step.assembly:
                        if verdict.as_built:
                            switched = self.robot.hv_outputs(True)
                            if not switched.success:
                                raise StepFailure(f"assembly {step.assembly!r} as built, but the HV outputs could "
                                                  f"not be switched on again: {switched.message}")
                            return f"assembly {step.assembly!r} as built (chain {verdict.chain}: {verdict.message})"
                        found = "; ".join(verdict.mistakes) or verdict.message
                        raise StepFailure(f"assembly {step.assembly!r} not as built: chain {verdict.chain}: {found}"
                                          f"; the HV outputs stay off until a swap is verified")
                ctx.cancel.wait(self.options.poll_period_s)
        finally:
            request.close()

    def _outputs_off(self, ctx: _Context) -> None:
        """Every HV output off (ramps refused meanwhile), seen off on every channel of the sequence."""
        switched = self.robot.hv_outputs(False)
        if not switched.success:
            raise StepFailure(f"the HV outputs could not be switched off for the swap: {switched.message}")
        while True:
            states = self.robot.channel_states()
            on = [c for c in ctx.sequence.channels if c in states and (states[c].stale or states[c].output_enabled)]
            if not on:
                return
            if self.clock() > ctx.deadline:
                raise StepFailure(f"timed out after {ctx.timeout:g} s waiting for the outputs of {on} to switch off")
            self._check_interrupts(ctx)
            ctx.cancel.wait(self.options.poll_period_s)

    # -- reactions --------------------------------------------------------------------------------------

    def _react(self, on_failure: str, sequence: Sequence) -> str:
        if on_failure == "estop":
            self.robot.stop_arm()
            return self._estop("on_failure: estop")
        return self._safe_stop(sequence)

    def _estop(self, reason: str) -> str:
        result = self.robot.estop()
        return f"{reason}; e-stop " + ("sent" if result.success else f"FAILED: {result.message}")

    def _safe_stop(self, sequence: Sequence) -> str:
        """Arm stops; every channel still on, or whose state is unknown, ramps to 0 V; e-stop if a ramp-down
        fails."""
        self.robot.stop_arm()
        states = self.robot.channel_states()
        live = [channel for channel in sequence.channels
                if channel not in states or states[channel].stale or states[channel].output_enabled
                or abs(states[channel].voltage) > self.options.off_voltage_v]
        problems, motions = [], {}
        for channel in live:
            try:
                motions[channel] = self.robot.ramp(channel, 0.0, 0.0)
            except RobotError as error:
                problems.append(f"{channel}: {error}")
        deadline = self.clock() + self.options.safe_stop_timeout_s
        for channel, motion in motions.items():
            if not motion.wait(max(0.0, deadline - self.clock())):
                motion.cancel()
                problems.append(f"{channel}: ramp to 0 V timed out")
            elif not motion.outcome().success:
                problems.append(f"{channel}: {motion.outcome().message}")
        if problems:
            return self._estop(f"ramp-down failed ({'; '.join(problems)})")
        return f"safe state: arm stopped, {live or 'no'} channel(s) ramped to 0 V"
