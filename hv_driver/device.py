"""One supply behind one port: its link, what it was last told per channel, and how the driver's intents (cut,
apply a command, read back, configure the device-side limits) become operations, chosen from the dialect's
capabilities. No safety decisions here: the supervisor makes them, the driver's loop calls this.
"""
import math
from dataclasses import dataclass

import serial

from .clock import MONOTONIC
from .config import ChannelConfig
from .dialects import CurrentSensing, Dialect, ProtocolError, StatusReport
from .errors import HvError
from .link import Link, LinkError
from .pulse import PulseTrain

# The device-side ramp is set this much faster than the host slew limit: fast enough to follow the
# streamed setpoints, slow enough to cap the slew if the host misbehaves.
DEVICE_RAMP_MARGIN = 1.2


class ConfigurationError(HvError, RuntimeError):
    """The device did not accept or read back the configured limits."""


@dataclass
class Sent:
    """What the device was last told on one channel."""

    setpoint: float = 0.0
    output_on: bool = False
    emergency: bool = False  # cut for a fault; released when the fault is reset
    cut_confirmed: bool = False  # the device has reported the cut output off since the cut (re-sent until then)
    pulse: PulseTrain | None = None        # the square train armed on the device (frequency and count sent)
    switching_since: float | None = None   # [s] when the device was told to start switching it
    armed: PulseTrain | None = None        # the last train armed (kept after it ended) ...
    frequency: float | None = None         # ... and the device's answer to its frequency [Hz] (quantised)
    counted: tuple[int, int] | None = None  # (done, total) of the switching train as the device last counted it


@dataclass(frozen=True)
class Reading:
    """One channel's readback: voltage [V], current [A] (None: the supply has no current readback), status, and
    when the voltage was measured (the answer's arrival on the device's clock: on a slow line the later queries
    of the same readback arrive tens of milliseconds after it)."""

    voltage: float
    current: float | None
    report: StatusReport
    measured_at: float


@dataclass(frozen=True)
class DeviceSide:
    """Device-side values read back at configuration, for the supervisor."""

    voltage_limit: float          # [V] the supply's own limit
    ramp_rate_v_per_s: float | None  # the device ramp, None when the host ramps


class Device:
    """The channels of one supply on one port: a pyserial URL or device path, or a pyserial-like port object
    (``write``, ``read``, ``in_waiting``, ``reset_input_buffer``, ``timeout``; e.g. an in-memory link to a simulated
    supply on a simulated clock). ``clock``: what the link's deadlines read and wait on (`hv_driver.clock`)."""

    def __init__(self, port, baudrate: int | None, dialect: Dialect, configs: list[ChannelConfig],
                 reply_timeout: float, clock=MONOTONIC):
        self._given_port = None if isinstance(port, str) else port
        port = port if isinstance(port, str) else getattr(port, "name", repr(port))
        self.port_name, self.dialect, self.configs = port, dialect, list(configs)
        self.clock = clock
        self.capabilities = dialect.capabilities
        self.baudrate = baudrate or dialect.default_baudrate
        self.reply_timeout = reply_timeout
        self.indices = [c.index for c in self.configs]
        self.device_id = ""
        self.link_error = ""  # last failed exchange, "" when the last one succeeded
        self.sent = {c.name: Sent() for c in self.configs}
        self._port = self.link = None

    # --- port --------------------------------------------------------------------------------------
    def open_port(self) -> None:
        if self._given_port is not None:
            self._port = self._given_port
            self._port.timeout = self.reply_timeout
            self.link = Link(self._port, self.dialect, self.reply_timeout, self.clock)
            return
        try:
            # exclusive: a second driver (another supervisor process) on the same supply is refused, not interleaved
            self._port = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=self.reply_timeout,
                                               write_timeout=self.reply_timeout, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as error:
            raise LinkError(f"cannot open {self.port_name!r}: {error}") from error
        self.link = Link(self._port, self.dialect, self.reply_timeout, self.clock)

    def close_port(self) -> None:
        if self._port is not None:
            self._port.close()

    def query(self, operation: str, channels=(), value: float | None = None):
        return self.link.query(operation, channels, value)

    def has(self, operation: str) -> bool:
        return operation in self.dialect.commands

    # --- session start -----------------------------------------------------------------------------
    def identify(self, expected_identity: str) -> str:
        self.device_id = self.query("identify")
        problem = self.dialect.identity_problem(self.device_id)
        if problem:
            raise ConfigurationError(f"device on {self.port_name}: {problem}")
        if expected_identity not in self.device_id:
            raise ConfigurationError(f"device on {self.port_name} identifies as {self.device_id!r}, "
                                     f"expected_identity={expected_identity!r} is not part of it")
        count = self.capabilities.channels_per_device
        if count is None:
            (count,) = self.query("read_channel_count")
        for config in self.configs:  # refused before anything is sent to a channel the supply lacks
            if config.index >= count:
                raise ConfigurationError(f"channel {config.name!r}: index {config.index} is not on the supply at "
                                         f"{self.port_name}, which has {count} channel(s) (indices 0-{count - 1})")
        return self.device_id

    def switch_all_off(self) -> None:
        """Known state: 0 V, output off (an output left on ramps down at the device ramp, if it has one)."""
        self.query("set_voltage", self.indices, 0.0)
        self.query("output_off", self.indices)
        for operation, value in self.dialect.session_settings():
            self.query(operation, self.indices, value)

    def configure(self) -> dict[str, DeviceSide]:
        """Device-side second line of defence, set and read back: ramp speed, current trip/limit, voltage limit."""
        sides = {}
        for config in self.configs:
            ch, settings, read_backs = [config.index], [], []
            ramp = config.slew_rate_v_per_s * DEVICE_RAMP_MARGIN if self.capabilities.device_ramp else None
            if ramp is not None:
                settings += [("set_ramp_up", ramp), ("set_ramp_down", ramp)]
                read_backs.append(("read_ramp", ramp))
            if self.capabilities.current is CurrentSensing.DEVICE_TRIP:
                current = config.current_trip_a * self.capabilities.device_current_margin
                for operation, value, read_back in self.dialect.device_trip_settings(current):
                    settings.append((operation, value))
                    read_backs += [(read_back, value)] if read_back else []
            if self.has("set_voltage_limit"):
                settings.append(("set_voltage_limit", config.max_voltage_v))
            for operation, value in settings:
                self.query(operation, ch, value)
            for operation, expected in read_backs:
                (actual,) = self.query(operation, ch)
                if not math.isclose(actual, expected, rel_tol=1e-3):
                    raise ConfigurationError(f"channel {config.name!r}: {operation} reads {actual:g}, "
                                             f"configured {expected:g}")
            (limit,) = self.query("read_voltage_limit", ch)
            sides[config.name] = DeviceSide(limit, ramp)
        return sides

    def found(self) -> dict[str, tuple[float, StatusReport]]:
        """Voltage and status of every channel as an earlier session left them."""
        statuses = [self.query(operation, self.indices) for operation in self.capabilities.status_operations]
        voltages = self.query("measure_voltage", self.indices)
        measured_at = self.clock()
        return {config.name: (voltage, self.dialect.status_report(*(s[k] for s in statuses)))
                for k, (config, voltage) in enumerate(zip(self.configs, voltages))}

    # --- control cycle -----------------------------------------------------------------------------
    def read(self) -> dict[str, Reading]:
        """Voltage, current (if the supply measures it) and status of every channel, one query each for all."""
        voltages = self.query("measure_voltage", self.indices)
        measured_at = self.clock()
        currents = ([None] * len(self.indices) if self.capabilities.current is CurrentSensing.NONE
                    else self.query("measure_current", self.indices))
        statuses = [self.query(operation, self.indices) for operation in self.capabilities.status_operations]
        for config in self.configs:  # a train the device switches: its own count, which ends it
            sent = self.sent[config.name]
            if sent.pulse is not None and sent.switching_since is not None:
                sent.counted = self.dialect.cycle_count(self.query("read_cycles", [config.index]))
        return {config.name: Reading(voltage, current, self.dialect.status_report(*(s[k] for s in statuses)),
                                     measured_at)
                for k, (config, voltage, current) in enumerate(zip(self.configs, voltages, currents))}

    def cut(self, configs: list[ChannelConfig]) -> None:
        """Outputs of faulted channels to 0 V and off at once: the device's emergency off where it has one (all in
        one line), else output off, then 0 V. A line written is not a cut made (a supply that does not answer
        settings may not have read it): the cut counts only once the device reports the output off
        (`confirm_cut`), and is sent again every cycle until then. Behind a failed exchange the lines go out at once,
        unanswered, rather than after the line has fallen quiet for a reply timeout."""
        if not configs:
            return
        indices = [c.index for c in configs]
        for config in configs:
            self.sent[config.name] = Sent(0.0, False, True)
        send = self.link.send if self.link.stale else self.query
        send("emergency_off" if self.capabilities.emergency_off else "output_off", indices)
        send("set_voltage", indices, 0.0)

    def unconfirmed_cuts(self, faulted: set[str]) -> list[ChannelConfig]:
        """The channels of ``faulted`` (names) whose cut the device has not yet confirmed: to be cut (again)."""
        return [c for c in self.configs if c.name in faulted and not self.sent[c.name].cut_confirmed]

    def confirm_cut(self, config: ChannelConfig, reading: "Reading") -> bool:
        """Take a readback after a cut: True when the device reports the output still on (the cut did not happen);
        an output reported off confirms the cut."""
        sent = self.sent[config.name]
        sent.cut_confirmed = not reading.report.output_on
        return reading.report.output_on

    def apply(self, config: ChannelConfig, setpoint: float, output_on: bool, pulse: PulseTrain | None = None,
              now: float = 0.0) -> None:
        """Send what changed on one channel since the last cycle; ``pulse``: a square train the device switches
        itself (armed at once, started on the first cycle at or after its start)."""
        sent, ch = self.sent[config.name], [config.index]
        if sent.emergency:  # faults were reset: release what the cut latched in the device
            if self.capabilities.emergency_off:
                self.query("emergency_clear", ch)
            if self.has("clear_events"):
                self.query("clear_events", ch)
            sent.emergency = sent.cut_confirmed = False  # the next cut must be confirmed afresh
        if output_on and pulse is not None:
            self._switch(config, pulse, now)
            return
        if output_on and not sent.output_on:
            self.query("set_voltage", ch, 0.0)
            self.query("output_on", ch)
            sent.setpoint, sent.output_on = 0.0, True
        if sent.pulse is not None:  # the train ended or was stopped: 0 V, and back to a plain output
            self.query("set_voltage", ch, 0.0)
            if output_on:
                self.query("output_on", ch)
            sent.setpoint, sent.pulse, sent.switching_since = 0.0, None, None
        if output_on and setpoint != sent.setpoint:
            self.query("set_voltage", ch, setpoint)
            sent.setpoint = setpoint
        if not output_on and sent.output_on:
            self.query("set_voltage", ch, 0.0)
            self.query("output_off", ch)
            sent.setpoint, sent.output_on = 0.0, False

    def _switch(self, config: ChannelConfig, train: PulseTrain, now: float) -> None:
        """Arm the device for ``train`` with its output off (0 V whatever the set voltage): amplitude, frequency,
        cycle count (it stops by itself after them even if the host dies); then start it with one line on the
        first cycle at or after its start, so the first edge is the device's own."""
        sent, ch = self.sent[config.name], [config.index]
        if sent.pulse is not train:
            self.query("output_off", ch)
            self.query("set_voltage", ch, train.amplitude)
            (sent.frequency,) = self.query("set_frequency", ch, train.frequency)
            self.query("set_cycles", ch, train.cycles)
            sent.pulse = sent.armed = train
            sent.setpoint, sent.output_on, sent.switching_since = train.amplitude, False, None
        self._start_if_due(config, train, now)

    def _start_if_due(self, config: ChannelConfig, train: PulseTrain, now: float) -> None:
        sent = self.sent[config.name]
        if sent.pulse is train and sent.switching_since is None and now >= train.start:
            self.query("start_switching", [config.index])
            sent.output_on, sent.switching_since, sent.counted = True, now, None

    def start_due_trains(self, pulses: dict[str, PulseTrain | None], now: float) -> None:
        """Start the armed trains whose start has come (``pulses``: channel name -> its running train): one line
        each, sent before any other exchange of the cycle, so trains of several supplies start together."""
        for config in self.configs:
            train = pulses.get(config.name)
            if train is not None:
                self._start_if_due(config, train, now)

    def count_ended(self, config: ChannelConfig) -> bool:
        """The device has switched every cycle of the running train by its own count (and so stopped by itself)."""
        sent = self.sent[config.name]
        return (sent.pulse is not None and sent.counted is not None
                and sent.counted[0] >= sent.counted[1] == sent.pulse.cycles)

    def reset(self) -> None:
        """The device's own reset (outputs off, Vset 0, defaults); the cut state is forgotten with it."""
        self.query("reset")
        self.sent = {c.name: Sent() for c in self.configs}

    def shut_down(self, emergency: bool) -> None:
        """Every output 0 V and off (emergency: cut first); best effort when the link is gone."""
        steps = (["emergency_off" if self.capabilities.emergency_off else "output_off"] if emergency else [])
        try:
            for operation in steps + ["set_voltage", "output_off"]:
                self.query(operation, self.indices, 0.0 if operation == "set_voltage" else None)
        except (LinkError, ProtocolError):
            if not emergency:
                try:
                    self.query("emergency_off" if self.capabilities.emergency_off else "output_off", self.indices)
                except (LinkError, ProtocolError):
                    pass  # the link is gone: the device-side limits (and watchdog, if it has one) remain
