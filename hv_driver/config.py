"""Per-channel configuration of the HV supply: hard limits and trip thresholds (SI units)."""
import math
from dataclasses import dataclass

from .errors import SettingError
from .ramp import MAX_RAMP_DURATION_S, slowest_slew_rate


def _require(condition: bool, parameter: str, value, expectation: str) -> None:
    if not condition:
        raise SettingError(f"{parameter}={value!r}: {expectation}")


@dataclass(frozen=True)
class ChannelConfig:
    """Limits of one output channel.

    name: label used by every API ("front", "back").
    index: channel number on its supply (0-based, as in ``(@0)``; 0 on a single-channel supply).
    device: which supply the channel is on: the position of its port in HvSupply's port list (0 for one supply).
    max_voltage_v: hard maximum [V]; the ceiling never exceeds it (the assembly's safe voltage and the
        supply's own limit may lower it further).
    slew_rate_v_per_s: maximum rate of change of the commanded voltage [V/s]; at least the rate that
        ramps max_voltage_v within ramp.MAX_RAMP_DURATION_S.
    current_trip_a: measured current above this trips OVER_CURRENT [A].
    mismatch_tolerance_v, mismatch_time_s: measured voltage further than ``mismatch_tolerance_v`` [V]
        from the commanded one for longer than ``mismatch_time_s`` [s] trips READBACK_MISMATCH.
    creep_voltage_v, max_time_at_voltage_s: optional creep guard; continuous time with the measured
        voltage at or above ``creep_voltage_v`` [V] longer than ``max_time_at_voltage_s`` [s] trips
        TIME_AT_VOLTAGE. Both None (default) disables it.
    """

    name: str
    index: int
    max_voltage_v: float = 3000.0
    slew_rate_v_per_s: float = 1000.0
    current_trip_a: float = 50e-6
    mismatch_tolerance_v: float = 100.0
    mismatch_time_s: float = 0.5
    creep_voltage_v: float | None = None
    max_time_at_voltage_s: float | None = None
    device: int = 0

    def __post_init__(self):
        _require(isinstance(self.name, str) and self.name != "", "name", self.name, "non-empty string")
        _require(isinstance(self.index, int) and self.index >= 0, "index", self.index, "integer >= 0")
        _require(isinstance(self.device, int) and self.device >= 0, "device", self.device, "integer >= 0")
        for parameter in ("max_voltage_v", "slew_rate_v_per_s", "current_trip_a", "mismatch_tolerance_v",
                          "mismatch_time_s"):
            value = getattr(self, parameter)
            _require(isinstance(value, (int, float)) and math.isfinite(value) and value > 0,
                     parameter, value, "finite number > 0")
        _require(self.slew_rate_v_per_s >= slowest_slew_rate(self.max_voltage_v), "slew_rate_v_per_s",
                 self.slew_rate_v_per_s, f">= {slowest_slew_rate(self.max_voltage_v):g} V/s, so a ramp over "
                 f"max_voltage_v={self.max_voltage_v:g} V ends within {MAX_RAMP_DURATION_S:g} s")
        _require((self.creep_voltage_v is None) == (self.max_time_at_voltage_s is None),
                 "creep_voltage_v", self.creep_voltage_v, "set together with max_time_at_voltage_s")
        for parameter in ("creep_voltage_v", "max_time_at_voltage_s"):
            value = getattr(self, parameter)
            _require(value is None or (math.isfinite(value) and value > 0), parameter, value,
                     "None or finite number > 0")
