"""Output dynamics of one simulated HV channel driving a DEA load (pure, time passed in).

The supply moves its output towards the set voltage at its configured ramp speed; the DEA is a
capacitor with a leakage resistance, so the supply current is C·dV/dt + V/R_leak. Switched off
(`:VOLT OFF`, a trip with action 1, `*RST`), the output ramps down at the configured ramp-down speed, as
the iseg manual says; an emergency off (or a trip with action 2 or 3) cuts it without ramp and the load
discharges through the supply's discharge resistor. An arc (film breakdown) collapses the voltage and
draws a large current until the output is switched off.
"""
import math
from dataclasses import dataclass, field

from hv_driver.dialects.iseg_edcp import ChannelEvent, ChannelStatus


@dataclass(frozen=True)
class DeaLoad:
    capacitance: float = 2e-9               # [F] a few stacked DEA blocks
    leakage_resistance: float = 50e9        # [Ohm] -> ~50 nA at 2.4 kV
    discharge_resistance: float = 10e6      # [Ohm] supply bleeder: tau = 20 ms with 2 nF
    arc_current: float = 2e-3               # [A] breakdown current
    arc_collapse_time: float = 2e-3         # [s] voltage collapse time constant during an arc
    current_averaging: float = 0.02         # [s] time constant of the current readback filter


@dataclass(frozen=True)
class ChannelDefaults:
    """Power-up (and *RST) configuration of a channel."""

    voltage_limit: float = 5000.0   # [V] hardware limit (:READ:VOLT:LIM?)
    ramp_speed: float = 100.0       # [V/s]
    max_ramp_speed: float = 20000.0 # [V/s] faster ramp settings are clamped to this
    current_limit: float = 2e-3     # [A]
    trip_time_ms: float = 0.0       # [ms]
    trip_action: int = 0            # 0 = flag only


@dataclass
class PlantChannel:
    defaults: ChannelDefaults = field(default_factory=ChannelDefaults)
    load: DeaLoad = field(default_factory=DeaLoad)
    voltage: float = 0.0            # true output voltage [V]
    current: float = 0.0            # true supply current [A]
    measured_current: float = 0.0   # averaged current readback [A]
    drift: float = 0.0              # readback error [V] (readback_drift fault)
    drift_rate: float = 0.0         # [V/s]
    arcing: bool = False
    ramping_down: bool = False      # switched off with ramp, still above 0 V
    off_at: float | None = None     # time the output last went from on to off

    def __post_init__(self):
        self.power_on_reset()

    def power_on_reset(self) -> None:
        """State after power-up or *RST: output off, Vset 0, default configuration."""
        d = self.defaults
        self.voltage_set = 0.0
        self.output_on = False
        self.emergency = False
        self.ramp_up = self.ramp_down = d.ramp_speed
        self.current_limit = d.current_limit
        self.trip_time_ms = d.trip_time_ms
        self.trip_action = d.trip_action
        self.current_trip = False
        self.events = ChannelEvent(0)
        self._over_limit_since: float | None = None

    # --- commands ----------------------------------------------------------------------------
    def switch_off(self, now: float, emergency: bool, ramp: bool = True) -> None:
        """Output off: ramped down at the ramp-down speed, or without ramp (``ramp`` False, or an emergency off)."""
        if self.output_on:
            self.off_at = now
            self.events |= ChannelEvent.EVENT_ON_TO_OFF
            self.ramping_down = ramp
        self.output_on = False
        self.arcing = False
        if emergency or not ramp:
            self.ramping_down = False
        if emergency:
            self.emergency = True
            self.voltage_set = 0.0
            self.events |= ChannelEvent.EVENT_EMERGENCY_OFF

    def switch_on(self) -> bool:
        """Switch on; refused (False) while an emergency off or a current trip is latched."""
        if self.emergency or self.current_trip:
            return False
        self.output_on = True
        return True

    # --- dynamics ----------------------------------------------------------------------------
    def step(self, now: float, dt: float) -> None:
        if dt <= 0:
            return
        load, before = self.load, self.voltage
        if self.arcing and self.output_on:
            self.voltage *= math.exp(-dt / load.arc_collapse_time)
        elif self.output_on:
            delta = self.voltage_set - self.voltage
            limit = (self.ramp_up if delta > 0 else self.ramp_down) * dt
            self.voltage += max(-limit, min(limit, delta))
        elif self.ramping_down:
            self.voltage = max(0.0, self.voltage - self.ramp_down * dt)
            self.ramping_down = self.voltage > 0.0
        else:
            self.voltage *= math.exp(-dt / (load.discharge_resistance * load.capacitance))
        self.current = load.capacitance * (self.voltage - before) / dt + self.voltage / load.leakage_resistance
        if self.arcing and self.output_on:
            self.current += load.arc_current
        self.measured_current += (self.current - self.measured_current) * -math.expm1(-dt / load.current_averaging)
        self.drift += self.drift_rate * dt
        self._device_trip(now)

    def _device_trip(self, now: float) -> None:
        """Delayed current trip (:CONF:TRIP:TIME / :CONF:TRIP:ACTION), the device's own defence."""
        if not (self.output_on and self.current > self.current_limit):
            self._over_limit_since = None
            return
        self._over_limit_since = now if self._over_limit_since is None else self._over_limit_since
        if self.trip_action in (1, 2, 3) and now - self._over_limit_since >= self.trip_time_ms / 1000.0:
            self.current_trip = True
            self.events |= ChannelEvent.EVENT_CURRENT_TRIP
            self.switch_off(now, emergency=False, ramp=self.trip_action == 1)  # 1 off with ramp, 2/3 without

    # --- readback ----------------------------------------------------------------------------
    @property
    def measured_voltage(self) -> float:
        return self.voltage + self.drift

    @property
    def status(self) -> ChannelStatus:
        status = ChannelStatus.IS_POSITIVE
        ramping = (self.output_on and abs(self.voltage_set - self.voltage) > 0.5) or self.ramping_down
        for flag, active in ((ChannelStatus.IS_ON, self.output_on),
                             (ChannelStatus.IS_VOLTAGE_RAMP, ramping),
                             (ChannelStatus.IS_CONSTANT_VOLTAGE, self.output_on and not ramping),
                             (ChannelStatus.IS_EMERGENCY_OFF, self.emergency),
                             (ChannelStatus.IS_ARC, self.arcing),
                             (ChannelStatus.IS_CURRENT_TRIP, self.current_trip)):
            if active:
                status |= flag
        return status
