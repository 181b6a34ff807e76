"""Per-channel configuration of the HV supply: hard limits and trip thresholds (SI units)."""
import math
from dataclasses import dataclass

from .ramp import MAX_RAMP_DURATION_S, slowest_slew_rate


def _require(condition: bool, parameter: str, value, expectation: str) -> None:
    if not condition:
        raise ValueError(f"{parameter}={value!r}: {expectation}")


@dataclass(frozen=True)
class ChannelConfig:
    """Limits of one output channel.

    name: label used by every API ("front", "back").
    index: channel number on the supply (0-based, as in ``(@0)``).
    max_voltage: hard maximum [V]; the ceiling never exceeds it.
    slew_rate: maximum rate of change of the commanded voltage [V/s]; at least the rate that ramps
        max_voltage within ramp.MAX_RAMP_DURATION_S.
    current_trip: measured current above this trips OVER_CURRENT [A].
    mismatch_tolerance, mismatch_time: measured voltage further than ``mismatch_tolerance`` [V]
        from the commanded one for longer than ``mismatch_time`` [s] trips READBACK_MISMATCH.
    creep_voltage, max_time_at_voltage: optional creep guard; continuous time with the measured
        voltage at or above ``creep_voltage`` [V] longer than ``max_time_at_voltage`` [s] trips
        TIME_AT_VOLTAGE. Both None (default) disables it.
    """

    name: str
    index: int
    max_voltage: float
    slew_rate: float = 1000.0
    current_trip: float = 50e-6
    mismatch_tolerance: float = 100.0
    mismatch_time: float = 0.5
    creep_voltage: float | None = None
    max_time_at_voltage: float | None = None

    def __post_init__(self):
        _require(isinstance(self.name, str) and self.name != "", "name", self.name, "non-empty string")
        _require(isinstance(self.index, int) and self.index >= 0, "index", self.index, "integer >= 0")
        for parameter in ("max_voltage", "slew_rate", "current_trip", "mismatch_tolerance", "mismatch_time"):
            value = getattr(self, parameter)
            _require(isinstance(value, (int, float)) and math.isfinite(value) and value > 0,
                     parameter, value, "finite number > 0")
        _require(self.slew_rate >= slowest_slew_rate(self.max_voltage), "slew_rate", self.slew_rate,
                 f">= {slowest_slew_rate(self.max_voltage):g} V/s, so a ramp over max_voltage="
                 f"{self.max_voltage:g} V ends within {MAX_RAMP_DURATION_S:g} s")
        _require((self.creep_voltage is None) == (self.max_time_at_voltage is None),
                 "creep_voltage", self.creep_voltage, "set together with max_time_at_voltage")
        for parameter in ("creep_voltage", "max_time_at_voltage"):
            value = getattr(self, parameter)
            _require(value is None or (math.isfinite(value) and value > 0), parameter, value,
                     "None or finite number > 0")
