"""Smooth voltage ramps: minimum-jerk profiles whose peak rate equals the allowed slew rate."""
import math
from dataclasses import dataclass

from .errors import SettingError

# Peak of d/ds (10 s^3 - 15 s^4 + 6 s^5) on [0, 1], reached at s = 1/2.
MIN_JERK_PEAK_RATE = 1.875
# Longest ramp accepted [s]: a slew rate that would take longer over a channel's range is refused, so an
# absurd rate (1e-9 V/s: thousands of years) is named at once instead of holding the channel.
MAX_RAMP_DURATION_S = 600.0


def slowest_slew_rate(span: float) -> float:
    """Lowest slew rate [V/s] that ramps ``span`` [V] within MAX_RAMP_DURATION_S."""
    return MIN_JERK_PEAK_RATE * span / MAX_RAMP_DURATION_S


@dataclass(frozen=True)
class MinimumJerkRamp:
    """Voltage moving from ``start`` to ``end`` along a minimum-jerk (quintic) profile.

    Zero rate and zero acceleration at both ends, so the DEA is neither jolted nor loaded with a
    current step; the duration is chosen so the peak rate equals ``slew_rate`` [V/s].
    """

    start: float
    end: float
    t0: float
    slew_rate: float

    @property
    def duration(self) -> float:
        return MIN_JERK_PEAK_RATE * abs(self.end - self.start) / self.slew_rate

    def value(self, t: float) -> float:
        """Voltage at time ``t`` [s] (held at the ends outside the ramp)."""
        if self.duration == 0.0 or t >= self.t0 + self.duration:
            return self.end
        s = max(0.0, (t - self.t0) / self.duration)
        shape = s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)
        return self.start + (self.end - self.start) * shape

    def finished(self, t: float) -> bool:
        return t >= self.t0 + self.duration


def check_slew_rate(slew_rate: float, maximum: float, span: float) -> float:
    """Validated slew rate: ``maximum`` when None/0, else a finite positive value <= maximum that ramps
    ``span`` [V] (the channel's range) within MAX_RAMP_DURATION_S."""
    if slew_rate is None or slew_rate == 0:
        return maximum
    if not (isinstance(slew_rate, (int, float)) and math.isfinite(slew_rate) and slew_rate > 0):
        raise SettingError(f"slew_rate={slew_rate!r}: finite number > 0 (or 0 for the configured rate)")
    if slew_rate > maximum:
        raise SettingError(f"slew_rate={slew_rate:g} V/s exceeds the configured slew limit {maximum:g} V/s")
    if slew_rate < (slowest := slowest_slew_rate(span)):
        raise SettingError(f"slew_rate={slew_rate:g} V/s is below {slowest:g} V/s, the slowest that ramps the "
                           f"channel's {span:g} V within the {MAX_RAMP_DURATION_S:g} s limit on a ramp's duration")
    return float(slew_rate)
