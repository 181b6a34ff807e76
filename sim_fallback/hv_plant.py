"""Output dynamics of one simulated HV channel driving a DEA load (pure, time passed in), for every simulated dialect.

A supply with a device ramp (iseg) moves its output towards the set voltage at its configured ramp speed; one
without (Keithley 2290, Peta-pico-Voltron) regulates towards it with a first-order lag whose time constant grows
with the load's capacitance. The DEA is a capacitor with a leakage resistance, so the supply current is
C·dV/dt + V/R_leak. Switched off with ramp (iseg `:VOLT OFF`, a trip with action 1, `*RST`), the output ramps down
at the configured ramp-down speed, as the iseg manual says; an emergency off, a trip with action 2 or 3, or a
supply without a ramp cuts it, and the load discharges through the supply's discharge resistor. An arc (film
breakdown) collapses the voltage and draws a large current until the output is switched off. Device-side
switching (Peta-pico-Voltron mode 2) alternates the target between 0 V and the set voltage on the device's own
clock, and it counts the cycles it switched; the rising and falling crossings of the output through a watched level
are recorded with their exact times.
"""
import math
from dataclasses import dataclass, field
from enum import IntFlag


class PlantEvent(IntFlag):
    """Latched events of a channel, until the simulated device clears them (each dialect maps them to its bits)."""

    ARC = 1 << 0
    ON_TO_OFF = 1 << 1
    EMERGENCY_OFF = 1 << 2
    CURRENT_TRIP = 1 << 3
    EXTERNAL_INHIBIT = 1 << 4


@dataclass(frozen=True)
class DeaLoad:
    capacitance: float = 2e-9               # [F] a few stacked DEA blocks
    leakage_resistance: float = 50e9        # [Ohm] -> ~50 nA at 2.4 kV
    discharge_resistance: float = 10e6      # [Ohm] supply bleeder: tau = 20 ms with 2 nF
    arc_current: float = 2e-3               # [A] breakdown current
    arc_collapse_time: float = 2e-3         # [s] voltage collapse time constant during an arc
    current_averaging: float = 0.02         # [s] time constant of the current readback filter


NOMINAL_CAPACITANCE = DeaLoad.capacitance  # [F] the load the regulation time constant is given for


@dataclass(frozen=True)
class ChannelDefaults:
    """Power-up (and reset) configuration of a channel."""

    voltage_limit: float = 5000.0   # [V] hardware limit
    ramp_speed: float | None = 100.0  # [V/s] device ramp; None: no device ramp (regulates with regulation_time_s)
    max_ramp_speed: float = 20000.0 # [V/s] faster ramp settings are clamped to this
    regulation_time_s: float = 0.002  # [s] output time constant without device ramp, with NOMINAL_CAPACITANCE
    current_limit: float = 2e-3     # [A]
    trip_time_ms: float = 0.0       # [ms]
    trip_action: int = 0            # 0 = flag only, 1 off with ramp, 2 and 3 off without ramp


@dataclass
class Switching:
    """Device-side switching between 0 V and the set voltage: ``frequency`` [Hz], ``duty``, ``cycles`` (0 = forever),
    started at ``start`` [s] on the device clock; each period on first, or (``off_first``) off first and on for its
    last ``duty``."""

    frequency: float
    duty: float
    cycles: int
    start: float
    off_first: bool = False

    @property
    def _on_phase(self) -> tuple[float, float]:
        """Where in a period the output is on (fractions of the period)."""
        return (1.0 - self.duty, 1.0) if self.off_first else (0.0, self.duty)

    def on(self, t: float) -> bool:
        phase = (t - self.start) * self.frequency
        low, high = self._on_phase
        return low <= phase - math.floor(phase) < high

    def time_at(self, cycles: float) -> float:
        """Device time after ``cycles`` periods. Edges and the end both come from here, so the last edge is the end
        exactly: a phase computed back from a large clock value can fall a rounding error short of the count."""
        return self.start + cycles / self.frequency

    def done(self, t: float) -> bool:
        return self.cycles > 0 and t >= self.time_at(self.cycles)

    def completed(self, t: float) -> int:
        return int(max(0.0, t - self.start) * self.frequency)

    def boundaries(self, t0: float, t1: float) -> list[float]:
        """Times of the edges (and of the end) in (t0, t1)."""
        times = []
        k = math.floor((t0 - self.start) * self.frequency)
        while True:
            for offset in (0, 1.0 - self.duty if self.off_first else self.duty):
                t = self.time_at(k + offset)
                if t0 < t < t1:
                    times.append(t)
            if self.time_at(k + 1) >= t1:
                return times
            k += 1


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
    watch_level: float | None = None  # [V] crossings of this level are recorded in rising_edges / falling_edges
    rising_edges: list = field(default_factory=list)
    falling_edges: list = field(default_factory=list)
    cycles_switched: int = 0        # cycles of the last device-side switching train, counted by the device

    def __post_init__(self):
        self.power_on_reset()

    def power_on_reset(self) -> None:
        """State after power-up or reset: output off, Vset 0, default configuration."""
        d = self.defaults
        self.voltage_set = 0.0
        self.output_on = False
        self.emergency = False
        self.ramp_up = self.ramp_down = d.ramp_speed
        self.current_limit = d.current_limit
        self.trip_time_ms = d.trip_time_ms
        self.trip_action = d.trip_action
        self.voltage_bounds = self.current_bounds = 0.0  # iseg :VOLT:BOU / :CURR:BOU (stored, not acted on)
        self.current_trip = False
        self.events = PlantEvent(0)
        self.switching: Switching | None = None
        self._over_limit_since: float | None = None

    # --- commands ----------------------------------------------------------------------------
    def switch_off(self, now: float, emergency: bool, ramp: bool = True) -> None:
        """Output off: ramped down at the ramp-down speed, or without ramp (``ramp`` False, an emergency off, or a
        supply without a device ramp)."""
        ramp = ramp and self.ramp_down is not None
        if self.switching is not None:  # stopped before its count: the cycles begun so far
            self.cycles_switched = self.switching.completed(now)
        if self.output_on:
            self.off_at = now
            self.events |= PlantEvent.ON_TO_OFF
            self.ramping_down = ramp
        self.output_on = False
        self.switching = None
        self.arcing = False
        if emergency or not ramp:
            self.ramping_down = False
        if emergency:
            self.emergency = True
            self.voltage_set = 0.0
            self.events |= PlantEvent.EMERGENCY_OFF

    def switch_on(self) -> bool:
        """Switch on; refused (False) while an emergency off or a current trip is latched."""
        if self.emergency or self.current_trip:
            return False
        self.output_on = True
        return True

    def start_switching(self, now: float, frequency: float, duty: float, cycles: int, off_first: bool = False) -> bool:
        """Switch between 0 V and the set voltage from ``now`` on (refused like `switch_on`)."""
        if not self.switch_on():
            return False
        self.switching = Switching(frequency, duty, cycles, now, off_first)
        self.cycles_switched = 0
        return True

    # --- dynamics ----------------------------------------------------------------------------
    def target(self, t: float) -> float:
        if self.switching is not None and not self.switching.on(t):
            return 0.0
        return self.voltage_set

    def step(self, now: float, dt: float) -> None:
        """Advance to ``now``; a device-side switching edge inside the step splits it, so edges keep their times."""
        if dt <= 0:
            return
        t = now - dt
        inside = [] if self.switching is None else self.switching.boundaries(t, now)
        for boundary in inside + [now]:
            self._advance(boundary, boundary - t)
            t = boundary
            if self.switching is not None and self.switching.done(t):
                self.cycles_switched = self.switching.cycles
                self.switching = None  # the counted cycles are over: output off, as the device does
                self.switch_off(t, emergency=False, ramp=False)

    def _advance(self, now: float, dt: float) -> None:
        if dt <= 0:
            return
        load, before = self.load, self.voltage
        # Target in the middle of the step: a step begins or ends on a switching edge, whose own time would
        # fall on either side of it by rounding.
        target = self.target(now - dt / 2)
        # How the output moves in this step (a ramp at ``rate``, or a first-order approach with time constant ``tau``
        # towards ``towards``), for the exact time of a watched crossing.
        rate = tau = None
        towards = target
        if self.arcing and self.output_on:
            tau, towards = load.arc_collapse_time, 0.0
            self.voltage *= math.exp(-dt / tau)
        elif self.output_on and self.ramp_up is not None:
            delta = target - self.voltage
            rate = self.ramp_up if delta > 0 else self.ramp_down
            self.voltage += max(-rate * dt, min(rate * dt, delta))
        elif self.output_on:
            tau = self.defaults.regulation_time_s * load.capacitance / NOMINAL_CAPACITANCE
            self.voltage += (target - self.voltage) * -math.expm1(-dt / tau)
        elif self.ramping_down:
            rate = self.ramp_down
            self.voltage = max(0.0, self.voltage - rate * dt)
            self.ramping_down = self.voltage > 0.0
        else:
            tau, towards = load.discharge_resistance * load.capacitance, 0.0
            self.voltage *= math.exp(-dt / tau)
        self._record_edge(now - dt, dt, before, towards, rate, tau)
        self.current = load.capacitance * (self.voltage - before) / dt + self.voltage / load.leakage_resistance
        if self.arcing and self.output_on:
            self.current += load.arc_current
        self.measured_current += (self.current - self.measured_current) * -math.expm1(-dt / load.current_averaging)
        self.drift += self.drift_rate * dt
        self._device_trip(now)

    def _record_edge(self, start: float, dt: float, before: float, target: float, rate: float | None,
                     tau: float | None) -> None:
        """A crossing of the watched level in the step from ``start``, timed by the step's own law (a ramp at
        ``rate`` or a first-order lag ``tau`` towards ``target``), so long steps keep exact edge times."""
        level = self.watch_level
        rising = level is not None and before < level <= self.voltage
        if level is None or not (rising or before >= level > self.voltage):
            return
        if rate is not None:
            into = abs(level - before) / rate
        elif tau is not None and (target > level if rising else target < level):
            into = tau * math.log((target - before) / (target - level))
        else:
            into = dt * (level - before) / (self.voltage - before)
        (self.rising_edges if rising else self.falling_edges).append(start + min(dt, into))

    def _device_trip(self, now: float) -> None:
        """Delayed current trip (trip time and action), the device's own defence."""
        if not (self.output_on and self.current > self.current_limit):
            self._over_limit_since = None
            return
        self._over_limit_since = now if self._over_limit_since is None else self._over_limit_since
        if self.trip_action in (1, 2, 3) and now - self._over_limit_since >= self.trip_time_ms / 1000.0:
            self.current_trip = True
            self.events |= PlantEvent.CURRENT_TRIP
            self.switch_off(now, emergency=False, ramp=self.trip_action == 1)  # 1 off with ramp, 2/3 without

    # --- readback ----------------------------------------------------------------------------
    @property
    def measured_voltage(self) -> float:
        return self.voltage + self.drift

    @property
    def ramping(self) -> bool:
        return (self.output_on and self.switching is None and abs(self.voltage_set - self.voltage) > 0.5) \
            or self.ramping_down
