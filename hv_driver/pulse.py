"""Periodic actuation: a pulse train between 0 V and an amplitude, planned against what the supply can do.

Pure logic, time passed in. `plan_pulse_train` checks a request against the channel limits and the supply's
capabilities and refuses, naming the limit, what the device cannot produce: square edges need device-side switching
(the board switches itself, e.g. a Peta-pico-Voltron; its frequency range, fixed duty and cycle count bound them);
smooth edges are minimum-jerk edges generated in the driver's loop, each within the slew limit, that must fit in
the shortest on/off phase and span at least two loop periods. A train's on-edges lie on a time grid shared by every
train of its frequency (time zero a whole number of periods on the driver's clock), so trains sent separately, e.g.
the two diagonal leg pairs of a gait, keep their phase relation.
"""
import math
from dataclasses import dataclass

from .config import ChannelConfig
from .dialects import Capabilities
from .errors import SettingError
from .ramp import MIN_JERK_PEAK_RATE, check_slew_rate

EDGES = ("smooth", "square")
# Loop periods a smooth edge must span at least (the loop streams it as setpoints).
MIN_EDGE_CYCLES = 2
# Lead before a train's time zero, to arm the device (amplitude, frequency, cycle count) before it starts: some
# loop periods, and at least LEAD_S for a loop slowed by many supplies on a loaded host.
LEAD_CYCLES = 3
LEAD_S = 0.3
# A streamed pulse whose setpoints never reached this fraction of the amplitude fell short.
SHORT_FRACTION = 0.95
# Bounds of any train: a DEA actuation cycle lasts well under a minute, so a slower one is a unit mistake (mHz for
# Hz) whose first edge could lie days away; and a train holds control of its channels for its whole duration.
MIN_FREQUENCY_HZ = 0.01
MAX_TRAIN_S = 3600.0


class PulseLimitError(SettingError):
    """A pulse train the supply cannot produce; the message names the limit."""


@dataclass(frozen=True)
class PulseTrain:
    """``cycles`` periods of ``amplitude`` [V] for ``duty`` of each period at ``frequency`` [Hz], the first on-edge
    at ``t0 + phase / frequency`` [s]. ``edge`` "smooth": minimum-jerk edges whose peak rate is ``slew_rate``
    [V/s], streamed by the driver's loop; "square": the device switches by itself (``slew_rate`` unused)."""

    amplitude: float
    frequency: float
    duty: float
    phase: float
    cycles: int
    edge: str
    slew_rate: float
    t0: float
    end: float = 0.0  # voltage once the train is over

    @property
    def period(self) -> float:
        return 1.0 / self.frequency

    @property
    def start(self) -> float:
        """Time of the first on-edge [s]."""
        return self.t0 + self.phase * self.period

    @property
    def stop(self) -> float:
        """Time the last period ends [s]."""
        return self.start + self.cycles * self.period

    @property
    def on_device(self) -> bool:
        return self.edge == "square"

    @property
    def edge_duration(self) -> float:
        return 0.0 if self.on_device else MIN_JERK_PEAK_RATE * self.amplitude / self.slew_rate

    def cycles_done(self, t: float) -> int:
        return max(0, min(self.cycles, math.floor((t - self.start) * self.frequency)))

    def value(self, t: float) -> float:
        """Setpoint at ``t`` [s]: the amplitude while the device switches (square), else the smooth waveform."""
        if t < self.start or t >= self.stop:
            return 0.0
        if self.on_device:
            return self.amplitude
        into = (t - self.start) % self.period
        rise, on = self.edge_duration, self.duty * self.period
        if into < on:
            shape = _min_jerk(into / rise) if into < rise else 1.0
        else:
            shape = 1.0 - _min_jerk((into - on) / rise) if into - on < rise else 0.0
        return self.amplitude * shape

    def finished(self, t: float) -> bool:
        return t >= self.stop


@dataclass
class PulseTally:
    """How many pulses of a streamed (smooth) train fell short: no setpoint in their period reached SHORT_FRACTION
    of the amplitude, or the loop skipped their period. A loop stalled for many periods cannot catch up (the
    slew allowance per cycle is capped at two of its sustained periods), so its pulses shrink instead of arriving late."""

    train: PulseTrain
    ramp_id: int
    short: int = 0
    longest_gap: float = 0.0  # [s] between consecutive loop cycles from the train's start: a stall shows here
    _period: int = -1  # period index of the samples so far (-1: before the first)
    _peak: float = 0.0
    _last: float | None = None  # time of the last sample [s]

    def add(self, t: float, setpoint: float) -> None:
        if t < self.train.start:
            self._last = t
            return
        if self._last is not None:
            self.longest_gap = max(self.longest_gap, t - self._last)
        self._last = t
        period = min(math.floor((t - self.train.start) * self.train.frequency), self.train.cycles)
        if period != self._period:
            self._close()
            self.short += max(0, period - self._period - 1)  # periods without a single sample
            self._period, self._peak = period, 0.0
        self._peak = max(self._peak, setpoint)

    def finish(self) -> None:
        """The train ended (or was stopped): the running period counts, later ones do not."""
        self._close()
        self._period = self.train.cycles

    def _close(self) -> None:
        if 0 <= self._period < self.train.cycles and self._peak < SHORT_FRACTION * self.train.amplitude:
            self.short += 1


def _min_jerk(s: float) -> float:
    s = min(1.0, max(0.0, s))
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _require(condition: bool, parameter: str, value, expectation: str) -> None:
    if not condition:
        raise SettingError(f"{parameter}={value!r}: {expectation}")


def plan_pulse_train(config: ChannelConfig, capabilities: Capabilities, dialect_name: str, now: float,
                     loop_period_s: float, amplitude: float, frequency: float, duty: float, phase: float, cycles: int,
                     edge: str, slew_rate: float | None = None) -> PulseTrain:
    """The train for one channel, or SettingError / PulseLimitError naming what does not fit. The amplitude is
    checked against the channel's ceiling by the supervisor."""
    _require(isinstance(frequency, (int, float)) and math.isfinite(frequency) and frequency >= MIN_FREQUENCY_HZ,
             "frequency", frequency, f"finite number >= MIN_FREQUENCY_HZ ({MIN_FREQUENCY_HZ:g} Hz)")
    _require(isinstance(duty, (int, float)) and 0 < duty < 1, "duty", duty, "between 0 and 1 (exclusive)")
    _require(isinstance(phase, (int, float)) and 0 <= phase < 1, "phase", phase, "in [0, 1)")
    _require(isinstance(cycles, int) and not isinstance(cycles, bool) and cycles >= 1, "cycles", cycles,
             "an integer >= 1")
    _require(edge in EDGES, "edge", edge, f"one of {', '.join(EDGES)}")
    _require((cycles + phase) / frequency <= MAX_TRAIN_S, "cycles", cycles,
             f"at most MAX_TRAIN_S ({MAX_TRAIN_S:g} s) of train: {cycles} cycles at {frequency:g} Hz "
             f"(phase {phase:g}) last {(cycles + phase) / frequency:g} s")
    _require(isinstance(amplitude, (int, float)) and math.isfinite(amplitude) and amplitude > 0, "amplitude",
             amplitude, "finite number > 0 [V]")
    name, shortest = config.name, min(duty, 1.0 - duty) / frequency
    if edge == "square":
        switching = capabilities.switching
        if switching is None:
            raise PulseLimitError(f"channel {name!r}: square edges need a supply that switches by itself; the "
                                  f"{dialect_name} supply does not (use smooth edges, generated in the driver's loop)")
        if not switching.min_frequency_hz <= frequency <= switching.max_frequency_hz:
            raise PulseLimitError(f"channel {name!r}: frequency {frequency:g} Hz outside the {dialect_name} supply's "
                                  f"switching range {switching.min_frequency_hz:g}-{switching.max_frequency_hz:g} Hz")
        if not math.isclose(duty, switching.duty, abs_tol=1e-9):
            raise PulseLimitError(f"channel {name!r}: duty {duty:g}, but the {dialect_name} supply switches with a "
                                  f"fixed duty of {switching.duty:g} (smooth edges allow any duty)")
        if cycles > switching.max_cycles:
            raise PulseLimitError(f"channel {name!r}: {cycles} cycles, the {dialect_name} supply counts at most "
                                  f"{switching.max_cycles}")
        slew = 0.0
    else:
        slew = check_slew_rate(slew_rate, config.slew_rate_v_per_s, config.max_voltage_v)
        edge_s = MIN_JERK_PEAK_RATE * amplitude / slew
        device = (f" (the device ramp is set to {1.2 * config.slew_rate_v_per_s:g} V/s)"
                  if capabilities.device_ramp else "")
        if edge_s > shortest:
            raise PulseLimitError(
                f"channel {name!r}: {frequency:g} Hz at {amplitude:g} V with duty {duty:g} needs edges of at most "
                f"{shortest * 1e3:.0f} ms; a smooth edge over {amplitude:g} V takes {edge_s * 1e3:.0f} ms at the slew "
                f"limit of {slew:g} V/s{device}")
        if edge_s < MIN_EDGE_CYCLES * loop_period_s:
            raise PulseLimitError(
                f"channel {name!r}: a smooth edge of {edge_s * 1e3:.1f} ms is shorter than {MIN_EDGE_CYCLES} periods "
                f"of the {1.0 / loop_period_s:g} Hz control loop that generates it (lower slew_rate)")
    t0 = math.ceil((now + max(LEAD_CYCLES * loop_period_s, LEAD_S)) * frequency) / frequency
    return PulseTrain(float(amplitude), float(frequency), float(duty), float(phase), cycles, edge, slew, t0)
