"""Safety supervisor of the HV supply: pure logic, no I/O, time passed in by the caller.

One `ChannelSupervisor` per output holds the commanded setpoint, the running ramp and the latched
faults; `Supervisor` adds who may command (`ControlClaim`), the supply-wide watchdogs (link, the
controlling client's heartbeat) and the e-stop. The driver calls `step(now)` once per control cycle and
sends the returned commands.

Rules enforced here:
- ceiling = min(hard maximum, assembly safe voltage, supply limit); a request above it is refused
  with `LimitError` naming the limit, and the streamed setpoint is still clamped to it;
- the setpoint rises and falls no faster than the channel's slew limit (a stalled loop catches up by
  at most two sustained periods' worth per cycle), except that it drops at once when the ceiling drops
  below it or a fault latches;
- only the client holding control (commands signed with its session token) may ramp or feed the heartbeat watchdog; the
  watchdog is on unless switched off on purpose (heartbeat_timeout_s=math.inf); a heartbeat counts from when it was
  sent (`ControlClaim.confirm`);
- the readback must follow the commands at the device's own ramp (`ReadbackCheck`);
- on a supply without current readback (breakdown guard on), a measured voltage far below a setpoint held for a
  moment, or a pulse train none of whose pulses reaches half its amplitude for two periods, is a film breakdown
  (BREAKDOWN);
- a pulse train (`PulseTrain`) runs in place of a ramp: smooth trains are streamed within the slew limit, square
  ones are switched by the device itself (the setpoint is their amplitude while it switches; stopping one drops the
  output to 0 V at once, one more square edge of the kind it was making);
- faults latch until `reset`; every fault but HEARTBEAT and NODE_LOST puts the output to 0 V and off at once
  (emergency off), a lost heartbeat or node ramps to 0 V at the slew limit and then switches off;
- after a reset the outputs stay off until enabled again (never resume by themselves);
- faults latching and clearing and control ending other than by a release are queued in `events`
  (hv_driver.events), for the node to log every one.
"""
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from .config import ChannelConfig
from .control import HEARTBEAT, ControlClaim, ramp_command
from .errors import HvError, SettingError, StateError
from .events import EventLog
from .faults import Fault, fault_names
from .pulse import PulseTally, PulseTrain
from .ramp import MinimumJerkRamp, check_slew_rate
from .readback import ReadbackCheck

# A lost heartbeat or node ramps down smoothly; every other fault cuts the output at once.
RAMP_DOWN_FAULTS = Fault.HEARTBEAT | Fault.NODE_LOST
IMMEDIATE_FAULTS = Fault(sum(Fault)) & ~RAMP_DOWN_FAULTS

# Breakdown guard (supplies without current readback): a readback below COLLAPSE_FRACTION of a setpoint of at least
# COLLAPSE_MIN_V held for COLLAPSE_SETTLE_S (the output regulates towards it), COLLAPSE_READBACKS times in a row.
COLLAPSE_FRACTION = 0.5
COLLAPSE_MIN_V = 50.0
COLLAPSE_SETTLE_S = 0.05
COLLAPSE_READBACKS = 2
# ... and while a pulse train runs whose on-phase spans at least PULSE_GUARD_MIN_CYCLES loop periods: no readback at
# or above COLLAPSE_FRACTION of its amplitude for PULSE_GUARD_PERIODS periods of observed time.
PULSE_GUARD_MIN_CYCLES = 3
PULSE_GUARD_PERIODS = 2.0

# A train the device switches ends by the device's own count (`ChannelSupervisor.device_count_ended`); the host ends it
# itself only as a fallback, this long after its own clock's end: the start line's latency (a loop period or a late
# cycle), the board's clock running slow against the host's (DEVICE_CLOCK_TOLERANCE of the train's duration) and one
# more readback of the count.
DEVICE_COUNT_MARGIN_S = 0.25
DEVICE_CLOCK_TOLERANCE = 1e-3

# The control loop's rate unless told otherwise [Hz]: a fault shows in the readback of the next cycle, so the period is
# most of the time from a fault to the cut (docs/hv_driver.md, "Thresholds chosen for safety"). Over a link whose
# exchanges take longer the loop runs as fast as the line allows; the period it sustains (`Supervisor.set_cycle_period`)
# is the time step unit of the slew credit, the readback check and the pulse guard.
DEFAULT_LOOP_RATE_HZ = 200.0
DEFAULT_PERIOD_S = 1.0 / DEFAULT_LOOP_RATE_HZ
# A cycle credits the slew allowance with its elapsed time up to this many periods (the loop's sustained period). The driver's loop keeps its
# schedule while a cycle ends within one period of its slot (`HvSupply._run`), so a loop that runs late but on its
# schedule keeps the timing of its ramps (a heartbeat ramp-down ends on time); one resuming from a stall moves by at
# most this many periods' worth instead of jumping by the whole stall's.
SLEW_CREDIT_PERIODS = 2
# The controlling client's heartbeat watchdog is on unless switched off on purpose with math.inf.
DEFAULT_HEARTBEAT_TIMEOUT_S = 2.0
# A link trips only when at least this many exchanges in a row failed (besides link_timeout_s since the first): a loop
# descheduled right after one failure would otherwise count its own stall as the supply's silence and trip without
# asking again. A supply that stops answering fails more than this within link_timeout_s (by default each failure
# takes a quarter of it), so its trip is not delayed.
LINK_MIN_FAILED_EXCHANGES = 2


class LimitError(SettingError):
    """A request exceeds a safety limit; the message names the limit and its value."""


class FaultLatchedError(HvError, RuntimeError):
    """A request was refused because faults are latched (reset them first)."""


@dataclass(frozen=True)
class ChannelCommand:
    """What the driver must command on one channel for this cycle."""

    setpoint: float        # [V]
    output_on: bool
    emergency_off: bool    # a fault is latched: output off without ramp, setpoint 0
    pulse: PulseTrain | None = None  # a square train the device switches by itself: armed, then from its start on


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


class ChannelSupervisor:
    """Limits, ramp and latched faults of one output channel."""

    def __init__(self, config: ChannelConfig, now: float = 0.0, nominal_period_s: float = DEFAULT_PERIOD_S,
                 events: EventLog | None = None):
        self.config = config
        self.events = EventLog() if events is None else events  # the supervisor's, shared by its channels
        self._clock = float(now) if _finite(now) else 0.0
        self.nominal_period_s = nominal_period_s
        self.setpoint = 0.0
        self.target = 0.0
        self.output_enabled = False
        self.faults = Fault(0)
        self._reasons: dict[Fault, str] = {}
        self.safe_voltage: float | None = None
        self.device_limit: float | None = None
        self._ramp: MinimumJerkRamp | PulseTrain | None = None
        self._off_at_zero = False
        self._readback = ReadbackCheck(config.mismatch_tolerance_v, config.mismatch_time_s, nominal_period_s,
                                      self._clock)
        self._creep_since: float | None = None
        self.breakdown_guard = False
        self._held = (0.0, self._clock)  # (setpoint, since when) as last commanded
        self._collapsed = 0              # readbacks in a row far below the held setpoint
        self._low_for = 0.0              # [s] observed time a running pulse train has not reached its guard level
        self._last_observed: float | None = None
        self.pulse_tally: PulseTally | None = None  # the last streamed train's short pulses (kept after it ends)
        self._counted_out: PulseTrain | None = None  # the device-switched train the device reported counted out
        self.ended_by_host: PulseTrain | None = None  # ... or the one the host ended by its fallback instead
        self.ramp_id = 0  # counts accepted ramp requests, so a waiting caller sees being superseded

    def set_cycle_period(self, period_s: float) -> None:
        """The period the loop sustains (see `Supervisor.set_cycle_period`)."""
        self.nominal_period_s = self._readback.max_interval_s = period_s

    # --- state -------------------------------------------------------------------------------
    def limits(self) -> dict[str, float]:
        """Every voltage limit in force, by name."""
        named = {"hard maximum": self.config.max_voltage_v, "assembly safe voltage": self.safe_voltage,
                 "supply limit": self.device_limit}
        return {name: value for name, value in named.items() if value is not None}

    @property
    def ceiling(self) -> float:
        return min(self.limits().values())

    @property
    def ramping(self) -> bool:
        return self._ramp is not None

    @property
    def pulse_train(self) -> PulseTrain | None:
        return self._ramp if isinstance(self._ramp, PulseTrain) else None

    @property
    def fault_text(self) -> str:
        return "; ".join(f"{fault_names(f)}: {reason}" for f, reason in self._reasons.items())

    def _now(self, now: float) -> float:
        """Monotonic clock: a time stamp that is not finite or runs backwards counts as no time."""
        if _finite(now) and now > self._clock:
            return float(now)
        return self._clock

    # --- limits ------------------------------------------------------------------------------
    def set_safe_voltage(self, voltage: float | None) -> None:
        """Set the assembly's safe voltage [V] (None = unknown, not a limit)."""
        if voltage is not None and not (_finite(voltage) and voltage >= 0):
            raise SettingError(f"safe_voltage={voltage!r}: finite number >= 0 or None")
        self.safe_voltage = None if voltage is None else float(voltage)

    def set_device_limit(self, voltage: float | None) -> None:
        """Set the supply's own voltage limit [V] as read from the device."""
        if voltage is not None and not (_finite(voltage) and voltage >= 0):
            raise SettingError(f"device_limit={voltage!r}: finite number >= 0 or None")
        self.device_limit = None if voltage is None else float(voltage)

    def set_device_ramp(self, rate: float | None) -> None:
        """The supply's own ramp speed [V/s] as read from the device (None: it has none and follows at once);
        the readback check expects the output to move, and to ramp down when switched off, at this rate."""
        if rate is not None and not (_finite(rate) and rate > 0):
            raise SettingError(f"device_ramp={rate!r}: finite number > 0 or None")
        self._readback.ramp_rate_v_per_s = None if rate is None else float(rate)

    def output_found(self, now: float, voltage: float) -> None:
        """The output was found at ``voltage`` [V] (left on by an earlier session): the readback check
        expects it to ramp down from there."""
        if not _finite(voltage):
            raise SettingError(f"voltage={voltage!r}: finite number")
        self._readback.found(self._now(now), float(voltage))

    def check_target(self, target: float) -> float:
        """Validated target [V]; raises ValueError / LimitError naming the violated limit."""
        if not _finite(target) or target < 0:
            raise SettingError(f"target={target!r} V: finite number >= 0")
        for name, limit in self.limits().items():
            if target > limit:
                raise LimitError(f"channel {self.config.name!r}: target {target:g} V exceeds the "
                                 f"{name} of {limit:g} V")
        return float(target)

    # --- requests ----------------------------------------------------------------------------
    def _refuse_if_faulted(self) -> None:
        if self.faults:
            raise FaultLatchedError(f"channel {self.config.name!r} has latched faults "
                                    f"({self.fault_text}); reset them first")

    def enable(self) -> None:
        """Switch the output on at 0 V."""
        self._refuse_if_faulted()
        if not self.output_enabled:
            self.setpoint = self.target = 0.0
            self.output_enabled = True
        self._off_at_zero = False

    def disable(self, now: float) -> None:
        """Ramp to 0 V at the slew limit, then switch the output off."""
        now = self._now(now)
        if self.output_enabled:
            self._start_ramp(now, 0.0, self.config.slew_rate_v_per_s)
            self._off_at_zero = True
            self.ramp_id += 1

    def ramp_to(self, now: float, target_v: float, slew_rate_v_per_s: float | None = None) -> int:
        """Start a smooth ramp to ``target_v``; returns the ramp id. Refuses, never clips."""
        now = self._now(now)
        self._refuse_if_faulted()
        if not self.output_enabled:
            raise StateError(f"channel {self.config.name!r}: output not enabled")
        target = self.check_target(target_v)
        slew = check_slew_rate(slew_rate_v_per_s, self.config.slew_rate_v_per_s, self.config.max_voltage_v)
        self._start_ramp(now, target, slew)
        self._off_at_zero = False
        self.ramp_id += 1
        return self.ramp_id

    def check_pulse(self, train: PulseTrain) -> None:
        """Refuse ``train`` (faults latched, output off, amplitude over a limit, a square train from a live output)."""
        self._refuse_if_faulted()
        if not self.output_enabled:
            raise StateError(f"channel {self.config.name!r}: output not enabled")
        self.check_target(train.amplitude)
        if train.on_device and self.setpoint > 0.0 and self.pulse_train is None:
            raise StateError(f"channel {self.config.name!r}: at {self.setpoint:g} V; square edges start from 0 V "
                             f"(ramp it down first)")

    def pulse(self, now: float, train: PulseTrain) -> int:
        """Run ``train`` in place of any ramp; returns its ramp id. Refuses, never clips."""
        now = self._now(now)
        self.check_pulse(train)
        self._stop_device_switching()
        self._ramp, self.target, self._low_for = train, train.amplitude, 0.0
        self._off_at_zero = False
        self.ramp_id += 1
        self.pulse_tally = None if train.on_device else PulseTally(train, self.ramp_id)
        return self.ramp_id

    def device_count_ended(self, train: PulseTrain) -> None:
        """The device reports every cycle of ``train`` (the one it switches) switched: the train is over."""
        self._counted_out = train

    def _stop_device_switching(self) -> None:
        """A square train the device switches stops at 0 V at once, one more edge of the kind it was making."""
        train = self.pulse_train
        if train is not None and train.on_device:
            self.setpoint = 0.0

    def _start_ramp(self, now: float, target: float, slew: float) -> None:
        self._stop_device_switching()
        if self.pulse_tally is not None and self._ramp is self.pulse_tally.train:  # a streamed train is stopped
            self.pulse_tally.finish()
        self._ramp = MinimumJerkRamp(self.setpoint, target, now, slew)
        self.target = target

    # --- faults ------------------------------------------------------------------------------
    def trip(self, fault: Fault, reason: str) -> None:
        """Latch ``fault``; outputs off at once (a lost heartbeat ramps down first)."""
        if fault not in self.faults:
            self.faults |= fault
            self._reasons[fault] = reason
            self.events.add(self._clock, logging.ERROR, f"channel {self.config.name!r}: fault latched: "
                                                        f"{fault_names(fault)}: {reason}")
        if fault & IMMEDIATE_FAULTS:
            self.setpoint = self.target = 0.0
            self.output_enabled = False
            self._ramp = None
            self._off_at_zero = False
        elif self.output_enabled and not self._off_at_zero:
            self._start_ramp(self._clock, 0.0, self.config.slew_rate_v_per_s)
            self._off_at_zero = True

    def observe(self, now: float, voltage: float, current: float | None, device_fault: str | None = None,
                device_over_current: bool = False) -> None:
        """Check one readback: measured voltage [V] and current [A] (None: the supply has no current readback),
        the device's own flags."""
        now = self._now(now)
        if not (_finite(voltage) and (current is None or _finite(current))):
            self.trip(Fault.LINK, f"readback not a finite number ({voltage!r} V, {current!r} A)")
            return
        if current is not None and abs(current) > self.config.current_trip_a:  # negative-polarity modules
            self.trip(Fault.OVER_CURRENT, f"measured {current:.3g} A above the trip level "
                                          f"{self.config.current_trip_a:.3g} A")
        if device_over_current:
            self.trip(Fault.OVER_CURRENT, "the supply reported a current trip")
        if device_fault:
            self.trip(Fault.DEVICE, device_fault)
        mismatch = self._readback.check(now, voltage)
        if mismatch:
            self.trip(Fault.READBACK_MISMATCH, mismatch)
        if self.breakdown_guard:
            self._check_collapse(now, voltage)
        self._last_observed = now
        if self.config.creep_voltage_v is not None and voltage >= self.config.creep_voltage_v:
            self._creep_since = now if self._creep_since is None else self._creep_since
            if now - self._creep_since > self.config.max_time_at_voltage_s:
                self.trip(Fault.TIME_AT_VOLTAGE, f"above {self.config.creep_voltage_v:g} V for more than "
                                                 f"{self.config.max_time_at_voltage_s:g} s")
        else:
            self._creep_since = None

    def _check_collapse(self, now: float, voltage: float) -> None:
        train = self.pulse_train
        if train is not None:
            self._check_pulses(now, voltage, train)
            return
        held, since = self._held
        if (self.output_enabled and held >= COLLAPSE_MIN_V and now - since >= COLLAPSE_SETTLE_S
                and voltage < COLLAPSE_FRACTION * held):
            self._collapsed += 1
        else:
            self._collapsed = 0
        if self._collapsed >= COLLAPSE_READBACKS:
            self.trip(Fault.BREAKDOWN, f"measured {voltage:.0f} V, below {COLLAPSE_FRACTION:g} x the held setpoint of "
                                       f"{held:.0f} V in {COLLAPSE_READBACKS} readbacks: the voltage collapsed (film "
                                       f"breakdown); this supply has no current readback")

    def _check_pulses(self, now: float, voltage: float, train: PulseTrain) -> None:
        """Every pulse must reach COLLAPSE_FRACTION of the amplitude; time counted as observed (a stalled loop adds
        at most one sustained period per readback), where the on-phase is long enough for the loop to see it."""
        if now < train.start or train.duty * train.period < PULSE_GUARD_MIN_CYCLES * self.nominal_period_s:
            return
        if voltage >= COLLAPSE_FRACTION * train.amplitude:
            self._low_for = 0.0
            return
        interval = 0.0 if self._last_observed is None else max(0.0, now - self._last_observed)
        self._low_for += min(interval, self.nominal_period_s)
        if self._low_for > PULSE_GUARD_PERIODS * train.period:
            self.trip(Fault.BREAKDOWN, f"no pulse of the {train.frequency:g} Hz train reached {COLLAPSE_FRACTION:g} x "
                                       f"its {train.amplitude:.0f} V for {PULSE_GUARD_PERIODS:g} periods: the voltage "
                                       f"collapsed (film breakdown); this supply has no current readback")

    def reset(self) -> None:
        """Clear the latched faults; the output stays off until enabled again."""
        if self.faults:
            self.events.add(self._clock, logging.INFO, f"channel {self.config.name!r}: faults "
                                                       f"{fault_names(self.faults)} cleared")
        self.faults = Fault(0)
        self._reasons.clear()
        self.setpoint = self.target = 0.0
        self.output_enabled = False
        self._ramp = None
        self._off_at_zero = False
        self._readback.reset()
        self._creep_since = None

    # --- control cycle -----------------------------------------------------------------------
    def step(self, now: float) -> ChannelCommand:
        """Advance to ``now`` and return the command for this cycle."""
        command = self._command(now)
        if command.pulse is not None and self._clock >= command.pulse.start:
            self._readback.switching(self._clock, command.setpoint)  # the device is anywhere from 0 V to it
        else:
            self._readback.command(self._clock, command.setpoint, ramped=not command.emergency_off)
        if command.setpoint != self._held[0]:
            self._held = (command.setpoint, self._clock)
        return command

    def _command(self, now: float) -> ChannelCommand:
        now = self._now(now)
        dt = min(now - self._clock, SLEW_CREDIT_PERIODS * self.nominal_period_s)
        self._clock = now
        if self.faults & IMMEDIATE_FAULTS:
            return ChannelCommand(0.0, False, True)
        if not self.output_enabled:
            self.setpoint = 0.0
            return ChannelCommand(0.0, False, False)
        ceiling = self.ceiling
        if self.target > ceiling:  # the ceiling dropped under a running ramp: re-plan towards it
            self._start_ramp(now, ceiling, self._ramp.slew_rate if self._ramp else self.config.slew_rate_v_per_s)
        desired = self._ramp.value(now) if self._ramp else self.target
        finished = self._ramp is not None and self._ramp.finished(now)
        train = self.pulse_train
        device_switched = train is not None and train.on_device
        if device_switched and now >= train.start:  # on until the device's count ends it (or the fallback)
            counted_out = self._counted_out is train
            finished = counted_out or now >= train.stop + DEVICE_COUNT_MARGIN_S + (
                DEVICE_CLOCK_TOLERANCE * (train.stop - train.start))
            if finished and not counted_out:
                self.ended_by_host = train
            desired = train.end if finished else train.amplitude
        if not device_switched:  # the device's own square edges are not the host's to slew
            allowance = self.config.slew_rate_v_per_s * dt
            desired = min(max(desired, self.setpoint - allowance), self.setpoint + allowance)
        self.setpoint = max(0.0, min(desired, ceiling))
        tally = self.pulse_tally
        if tally is not None and self._ramp is tally.train:
            tally.add(now, self.setpoint)
        if finished and self.setpoint == self._ramp.end:
            self.target, self._ramp = self._ramp.end, None
        if self._off_at_zero and self._ramp is None and self.setpoint == 0.0:
            self.output_enabled = self._off_at_zero = False
        pulse = self._ramp if device_switched and self._ramp is train else None
        return ChannelCommand(self.setpoint, self.output_enabled, False, pulse)


class Supervisor:
    """All channels of one supply, who may command them, the link and heartbeat watchdogs, the e-stop.

    heartbeat_timeout_s: the controlling client must show a sign of life (a heartbeat or a ramp request
        with its token) this often, or its control lapses and every output it energised ramps to 0 V
        (HEARTBEAT). math.inf switches the watchdog off; that takes this deliberate value, None is refused.
    nominal_period_s: the control loop's period (the unit of the slew credit's cap, the readback check's), until
        the loop reports the period it sustains (`set_cycle_period`).
    """

    def __init__(self, configs: list[ChannelConfig], *, link_timeout_s: float,
                 heartbeat_timeout_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S,
                 nominal_period_s: float = DEFAULT_PERIOD_S, now: float = 0.0):
        if not configs:
            raise SettingError("channels: at least one ChannelConfig")
        for parameter, values in (("channel names", [c.name for c in configs]),
                                  ("channel indices", [(c.device, c.index) for c in configs])):
            if len(set(values)) != len(values):
                raise SettingError(f"{parameter} must be unique, got {values}")
        if not (_finite(link_timeout_s) and link_timeout_s > 0):
            raise SettingError(f"link_timeout_s={link_timeout_s!r}: finite number > 0")
        if not (isinstance(heartbeat_timeout_s, (int, float)) and heartbeat_timeout_s > 0):  # also refuses NaN
            raise SettingError(f"heartbeat_timeout_s={heartbeat_timeout_s!r}: a number of seconds > 0, or math.inf "
                               f"to switch the heartbeat watchdog off on purpose")
        if not (_finite(nominal_period_s) and nominal_period_s > 0):
            raise SettingError(f"nominal_period_s={nominal_period_s!r}: finite number > 0")
        self.link_timeout_s = float(link_timeout_s)
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self._clock = float(now) if _finite(now) else 0.0
        self.events = EventLog()
        self.channels = {c.name: ChannelSupervisor(c, self._clock, nominal_period_s, self.events) for c in configs}
        self.control = ControlClaim(self.heartbeat_timeout_s)
        # Per supply (device): start and count of the current run of failed exchanges (None while its link
        # answers). Timing the failures, not the gap since the last success, keeps a host that was merely
        # descheduled (a loaded machine) from tripping while a supply that stops answering still trips on time.
        self._link_failing: dict[int, tuple[float, int] | None] = {c.device: None for c in configs}

    def set_cycle_period(self, period_s: float) -> None:
        """The period the control loop sustains: its nominal one, or longer on a line whose exchanges take longer.
        The slew credit, the readback check and the pulse guard count time in this unit, so that a stall (a gap
        of many periods) is discounted while a loop that is merely slow, every cycle, keeps its ramps' times and
        trips on time."""
        if not (_finite(period_s) and period_s > 0):
            raise SettingError(f"period_s={period_s!r}: finite number > 0")
        for channel in self.channels.values():
            channel.set_cycle_period(period_s)

    @property
    def heartbeat_watchdog_off(self) -> bool:
        return math.isinf(self.heartbeat_timeout_s)

    @property
    def estop_latched(self) -> bool:
        return any(Fault.ESTOP in c.faults for c in self.channels.values())

    def _now(self, now: float) -> float:
        if _finite(now) and now > self._clock:
            self._clock = float(now)
        return self._clock

    def channel(self, name: str) -> ChannelSupervisor:
        try:
            return self.channels[name]
        except (KeyError, TypeError):
            raise SettingError(f"channel={name!r}: unknown, configured are {sorted(self.channels)}") from None

    def link_ok(self, now: float, device: int = 0) -> None:
        """A complete, valid exchange with supply ``device`` finished at ``now``."""
        self._now(now)
        self._link_failing[device] = None

    def link_failed(self, now: float, device: int = 0) -> None:
        """An exchange with supply ``device`` failed at ``now`` (no, partial, garbled or wrong answer)."""
        now = self._now(now)
        since, failed = self._link_failing.get(device) or (now, 0)
        self._link_failing[device] = (since, failed + 1)

    # --- who may command ---------------------------------------------------------------------
    def claim_control(self, client: str, now: float, nonce: str = "") -> str:
        """Take control as ``client``; returns the session token (ControlError while another holds it; ``nonce``:
        `ControlClaim.claim`). What a lapsed session left energised trips first: a new client never inherits
        outputs it did not raise."""
        now = self._now(now)
        self._watch_control(now)
        return self.control.claim(client, now, nonce)

    def release_control(self, token: str, now: float) -> str:
        """End the session of ``token`` (the session token or a signed release, `ControlClaim.release`); every output it left energised ramps to 0 V (no client watches it)."""
        now = self._now(now)
        owner = self.control.release(token, now)
        for channel in self.channels.values():
            if channel.output_enabled and not channel.faults and channel.target > 0.0:
                channel.ramp_to(now, 0.0)
        return owner

    def heartbeat(self, now: float, token: str, sent: float | None = None) -> None:
        """Sign of life of the controlling client (``token``: its session token or a signed HEARTBEAT; ControlError
        for anything else), sent at ``sent`` (default: ``now``)."""
        self.control.confirm(token, self._now(now), HEARTBEAT, sent)

    # --- requests ----------------------------------------------------------------------------
    def enable(self, name: str, now: float) -> None:
        self._now(now)
        self.channel(name).enable()

    def ramp_to(self, name: str, now: float, target_v: float, slew_rate_v_per_s: float | None = None, *,
                token: str) -> int:
        """Start a ramp on one channel for the client holding control (``token``: its session token or the signed
        `ramp_command`); the request counts as its sign of life."""
        now = self._now(now)
        channel = self.channel(name)
        self.control.confirm(token, now, ramp_command(name, target_v, slew_rate_v_per_s))
        return channel.ramp_to(now, target_v, slew_rate_v_per_s)

    def pulse(self, names: list[str], now: float, plan: Callable[[ChannelConfig, float], PulseTrain], *,
              token: str, command: tuple = ("pulse",)) -> tuple[dict[str, PulseTrain], dict[str, int]]:
        """Start a pulse train, ``plan(config, now)`` (e.g. `plan_pulse_train`), on each channel of ``names`` for
        the client holding control (all or none); returns the train and the ramp id of each. ``token``: the session
        token, or a signed ``command`` (`pulse_command` of the request ``plan`` was made from). The request counts as
        the client's sign of life."""
        now = self._now(now)
        channels = [self.channel(name) for name in names]
        if not channels or len(set(names)) != len(names):
            raise SettingError(f"channels={names!r}: one or more distinct channel names")
        self.control.confirm(token, now, command)
        trains = {channel.config.name: plan(channel.config, now) for channel in channels}
        for channel in channels:  # every check before anything changes
            channel.check_pulse(trains[channel.config.name])
        return trains, {channel.config.name: channel.pulse(now, trains[channel.config.name]) for channel in channels}

    def set_safe_voltage(self, voltage: float | None) -> None:
        for channel in self.channels.values():
            channel.set_safe_voltage(voltage)

    def estop(self) -> None:
        """Every output off at once (ESTOP); open to everyone, and it ends the control session."""
        self._end_control(self._clock, "control ended by an emergency stop")
        for channel in self.channels.values():
            channel.trip(Fault.ESTOP, "emergency stop")

    def node_lost(self, now: float, reason: str) -> None:
        """The node this supervisor serves is gone: its client's session ends and every channel latches NODE_LOST
        (energised outputs ramp to 0 V). Nothing is energised again until a client claims control and resets."""
        self._end_control(self._now(now), reason)
        self.trip_all(Fault.NODE_LOST, reason)

    def _end_control(self, now: float, reason: str) -> None:
        """End the session (if any) for ``reason``, other than by its release: an event."""
        if self.control.owner is not None:
            self.events.add(now, logging.WARNING, reason)
        self.control.end(reason)

    def trip_all(self, fault: Fault, reason: str) -> None:
        for channel in self.channels.values():
            channel.trip(fault, reason)

    def reset(self, now: float, all_channels: bool = False) -> list[str]:
        """Clear the latched faults of the faulted channels (of every channel with ``all_channels``, which also
        switches healthy outputs off); returns the names reset. A cause still present trips again."""
        self._now(now)
        names = [name for name, channel in self.channels.items() if all_channels or channel.faults]
        for name in names:
            self.channels[name].reset()
        return names

    def step(self, now: float) -> dict[str, ChannelCommand]:
        now = self._now(now)
        for device, failing in self._link_failing.items():
            if failing and now - failing[0] > self.link_timeout_s and failing[1] >= LINK_MIN_FAILED_EXCHANGES:
                for channel in self.channels.values():
                    if channel.config.device == device:
                        channel.trip(Fault.LINK, f"no valid reply from the supply for more than "
                                                 f"{self.link_timeout_s:g} s")
        self._watch_control(now)
        return {name: channel.step(now) for name, channel in self.channels.items()}

    def _watch_control(self, now: float) -> None:
        """End a silent session; without a live client, trip every output held or raised above 0 V (one on its
        way to 0 V needs no client)."""
        if self.control.lapse_if_silent(now):
            self.events.add(now, logging.WARNING, self.control.ended)
        if not self.heartbeat_watchdog_off and self.control.owner is None:
            reason = self.control.ended or "no client holds control"
            for channel in self.channels.values():
                if channel.output_enabled and channel.target > 0.0:
                    channel.trip(Fault.HEARTBEAT, reason)
