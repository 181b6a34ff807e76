"""HvSupply: owns the serial link, runs the supervised control loop in its own thread.

Thread model: one loop thread does all serial I/O; the public methods (thread-safe) only change
the supervisor's state under a lock and wake the loop, which applies the change within one cycle.
"""
import atexit
import logging
import math
import signal
import threading
import time
import weakref
from dataclasses import dataclass

import serial

from .config import ChannelConfig
from .dialects import Dialect, IsegEdcp, ProtocolError
from .dialects.iseg_edcp import TRIP_ACTION_OFF_WITHOUT_RAMP
from .errors import HvError, SettingError, StateError
from .faults import Fault
from .link import Link, LinkError
from .supervisor import DEFAULT_HEARTBEAT_TIMEOUT_S, ChannelCommand, Supervisor

# The device-side ramp is set this much faster than the host slew limit: fast enough to follow the
# streamed setpoints, slow enough to cap the slew if the host misbehaves.
DEVICE_RAMP_MARGIN = 1.2
# Device-side current trip limit relative to the host trip level, and its delay: a second line of
# defence that acts only if the host loop fails to.
DEVICE_CURRENT_MARGIN = 1.5
DEVICE_TRIP_TIME_S = 0.1

log = logging.getLogger(__name__)


class ConfigurationError(HvError, RuntimeError):
    """The device did not accept or read back the configured limits."""


@dataclass(frozen=True)
class ChannelSnapshot:
    name: str
    index: int
    setpoint: float            # [V] commanded to the supply
    target: float              # [V] end of the running ramp
    measured_voltage: float    # [V]
    measured_current: float    # [A]
    ceiling: float             # [V]
    output_enabled: bool
    ramping: bool
    faults: Fault
    fault_text: str


@dataclass(frozen=True)
class SupplySnapshot:
    device_id: str
    port: str
    estop: bool
    link_error: str            # last failed exchange, "" when the last one succeeded
    stamp: float               # clock time [s] of the last control cycle's setpoints
    channels: tuple[ChannelSnapshot, ...]
    controller: str = ""       # name of the client holding control, "" when none
    heartbeat_age_s: float | None = None  # since the controlling client's last sign of life
    heartbeat_timeout_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S  # inf = watchdog off

    def channel(self, name: str) -> ChannelSnapshot:
        return next(c for c in self.channels if c.name == name)


@dataclass(frozen=True)
class _Applied:
    """Ramp state of one channel as of the last cycle whose commands reached the device."""

    ramp_id: int = 0
    ramping: bool = False
    settled: bool = True  # the readback of that cycle within the mismatch tolerance of the setpoint


@dataclass
class _Sent:
    """What the device was last told on one channel."""

    setpoint: float = 0.0
    output_on: bool = False
    emergency: bool = False


class RampHandle:
    """A running ramp of one channel: ``wait``, ``done``, ``cancel`` (ramps to 0 V)."""

    def __init__(self, supply: "HvSupply", channel: str, ramp_id: int, target: float):
        self._supply, self.channel, self._ramp_id, self.target = supply, channel, ramp_id, target

    def _state(self):
        """The channel, and whether this ramp is over: superseded, faulted, or its end sent and read back."""
        ch = self._supply._supervisor.channel(self.channel)
        applied = self._supply._applied[self.channel]
        finished = applied.ramp_id == self._ramp_id and not applied.ramping and applied.settled
        return ch, ch.ramp_id != self._ramp_id or bool(ch.faults) or finished

    @property
    def done(self) -> bool:
        with self._supply._lock:
            return self._state()[1]

    @property
    def message(self) -> str:
        """Why the ramp ended ("" while it runs)."""
        with self._supply._lock:
            ch, done = self._state()
            if not done:
                return ""
            if ch.faults:
                return f"aborted by faults: {ch.fault_text}"
            if ch.ramp_id != self._ramp_id:
                return "superseded by a later request"
            if ch.setpoint != self.target:
                return f"stopped at {ch.setpoint:g} V: ceiling lowered to {ch.ceiling:g} V"
            return f"reached {self.target:g} V"

    @property
    def succeeded(self) -> bool:
        return self.message.startswith("reached")

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the ramp ends or ``timeout`` [s] passes; True when it ended."""
        with self._supply._cycle_done:
            return self._supply._cycle_done.wait_for(lambda: self._state()[1], timeout)

    def cancel(self) -> "RampHandle | None":
        """Ramp the channel back to 0 V if this ramp is still the running one; returns that ramp."""
        down = None
        with self._supply._lock:
            ch = self._supply._supervisor.channel(self.channel)
            if ch.ramp_id == self._ramp_id and not ch.faults and ch.output_enabled:
                down = RampHandle(self._supply, self.channel, ch.ramp_to(self._supply._clock(), 0.0), 0.0)
        self._supply._wake.set()
        return down


class HvSupply:
    """A multi-channel HV supply behind the safety supervisor.

    port: pyserial URL or device path (a pty path for the simulated supply).
    channels: one ChannelConfig per output used.
    loop_rate_hz: control loop rate; each cycle sends new setpoints and reads voltage, current
        and status of every channel.
    link_timeout_s: no valid reply for this long trips LINK.
    heartbeat_timeout_s: the client holding control (`claim_control`) must call `heartbeat(token)` (or
        ramp) this often, or its control lapses and its energised outputs ramp to 0 V (HEARTBEAT).
        math.inf switches the watchdog off on purpose; the driver then warns at every `open()`.
    reply_timeout_s: time allowed for one echoed answer (default: a quarter of link_timeout_s).
    expected_identity: text the device's identification (``*IDN?``) must contain, e.g. its model, checked at
        `open`; "" checks nothing.
    """

    def __init__(self, port: str, baudrate: int | None = None, channels: list[ChannelConfig] = (),
                 loop_rate_hz: float = 100.0, link_timeout_s: float = 0.5,
                 heartbeat_timeout_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S, reply_timeout_s: float | None = None,
                 dialect: Dialect | None = None, handle_signals: bool = True, clock=time.monotonic,
                 expected_identity: str = ""):
        if not (math.isfinite(loop_rate_hz) and 1.0 <= loop_rate_hz <= 1000.0):
            raise SettingError(f"loop_rate_hz={loop_rate_hz!r}: between 1 and 1000")
        reply_timeout_s = link_timeout_s / 4 if reply_timeout_s is None else reply_timeout_s
        if not (math.isfinite(reply_timeout_s) and 0 < reply_timeout_s < link_timeout_s):
            raise SettingError(f"reply_timeout_s={reply_timeout_s!r}: > 0 and below link_timeout_s")
        self.port_name = port
        self.expected_identity = expected_identity
        self.dialect = dialect or IsegEdcp()
        self.baudrate = baudrate or self.dialect.default_baudrate
        self.configs = list(channels)
        self._clock = clock
        self._period = 1.0 / loop_rate_hz
        self._supervisor = Supervisor(self.configs, link_timeout_s=link_timeout_s,
                                      heartbeat_timeout_s=heartbeat_timeout_s, nominal_period_s=self._period,
                                      now=clock())
        self._reply_timeout = reply_timeout_s
        self._link_timeout = link_timeout_s
        self._handle_signals = handle_signals
        self._lock = threading.RLock()
        self._cycle_done = threading.Condition(self._lock)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._port = self._link = None
        self._sent = {c.name: _Sent() for c in self.configs}
        self._measured = {c.name: (0.0, 0.0) for c in self.configs}
        self._applied = {c.name: _Applied() for c in self.configs}
        self._reconfigure = self._device_reset = False
        self._link_error = ""
        self._cycles = 0
        self._stamp = clock()
        self.device_id = ""

    # --- lifecycle -----------------------------------------------------------------------------
    def open(self) -> "HvSupply":
        """Open the port, identify the supply, set and read back its limits, start the loop."""
        try:
            self._port = serial.serial_for_url(self.port_name, baudrate=self.baudrate,
                                               timeout=self._reply_timeout, write_timeout=self._reply_timeout)
        except (serial.SerialException, OSError, ValueError) as error:
            raise LinkError(f"cannot open {self.port_name!r}: {error}") from error
        self._link = Link(self._port, self.dialect, self._reply_timeout)
        failing_since = None
        try:
            while True:
                try:
                    self._start_session()
                    break
                except (LinkError, ProtocolError):
                    # The link watchdog's rule: only answers failing for longer than link_timeout_s mean a dead
                    # supply; one still starting up (a simulator on a loaded host) gets the same grace.
                    failing_since = self._clock() if failing_since is None else failing_since
                    if self._clock() - failing_since > self._link_timeout:
                        raise
        except (LinkError, ProtocolError, ConfigurationError):
            self._port.close()
            raise
        if self._supervisor.heartbeat_watchdog_off:
            log.warning("heartbeat watchdog OFF (heartbeat_timeout_s=inf) on %s: energised outputs stay on "
                        "when the controlling client dies", self.port_name)
        self._supervisor.link_ok(self._clock())
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"hv-loop {self.port_name}", daemon=True)
        self._thread.start()
        self._install_exit_guards()
        return self

    def _start_session(self) -> None:
        """Identify, check the channels, switch every output off, configure the device side and take in what
        an earlier session left (outputs still up, latched device faults). Every step may be repeated."""
        self.device_id = self._link.query("identify")
        if self.expected_identity not in self.device_id:
            raise ConfigurationError(f"device on {self.port_name} identifies as {self.device_id!r}, "
                                     f"expected_identity={self.expected_identity!r} is not part of it")
        self._check_channels(*self._link.query("read_channel_count"))
        indices = [c.index for c in self.configs]
        self._link.query("set_voltage", indices, 0.0)  # known state: 0 V, off (an output left on ramps down)
        self._link.query("output_off", indices)
        self._configure_device()
        registers = zip(self._link.query("read_status", indices), self._link.query("read_event_status", indices))
        voltages = self._link.query("measure_voltage", indices)
        with self._lock:
            for config, (status, events), voltage in zip(self.configs, registers, voltages):
                channel = self._supervisor.channel(config.name)
                channel.output_found(self._clock(), voltage)
                report = self.dialect.status_report(status, events)
                if report.fault:  # a latched device fault survives reconnects until reset on purpose
                    channel.trip(Fault.DEVICE, report.fault)
                    self._sent[config.name].emergency = True

    def _check_channels(self, count: int) -> None:
        """Refuse configured channel indices the supply does not have (it reports its channel count)."""
        for config in self.configs:
            if config.index >= count:
                raise ConfigurationError(f"channel {config.name!r}: index {config.index} is not on this supply, "
                                         f"which has {count} channel(s) (indices 0-{count - 1})")

    def _configure_device(self) -> None:
        """Device-side second line of defence: ramp speed, current limit and trip; read back."""
        for config in self.configs:
            ch = [config.index]
            ramp = config.slew_rate_v_per_s * DEVICE_RAMP_MARGIN
            current = config.current_trip_a * DEVICE_CURRENT_MARGIN
            trip_ms = DEVICE_TRIP_TIME_S * 1000.0
            for operation, value in (("set_ramp_up", ramp), ("set_ramp_down", ramp),
                                     ("set_current_limit", current), ("set_trip_time", trip_ms),
                                     ("set_trip_action", TRIP_ACTION_OFF_WITHOUT_RAMP)):
                self._link.query(operation, ch, value)
            for operation, expected in (("read_ramp", ramp), ("read_current_limit", current),
                                        ("read_trip_time", trip_ms)):
                (actual,) = self._link.query(operation, ch)
                if not math.isclose(actual, expected, rel_tol=1e-3):
                    raise ConfigurationError(f"channel {config.name!r}: {operation} reads {actual:g}, "
                                             f"configured {expected:g}")
            (limit,) = self._link.query("read_voltage_limit", ch)
            with self._lock:
                channel = self._supervisor.channel(config.name)
                channel.set_device_limit(limit)
                channel.set_device_ramp(ramp)  # read back above: outputs move, and ramp down when off, at it

    def close(self, ramp_down_timeout: float = 5.0) -> None:
        """Ramp every output to 0 V and switch it off, stop the loop, close the port."""
        if self._thread is None:
            return
        for name in self._supervisor.channels:
            self.disable(name)
        self.wait_outputs_off(ramp_down_timeout)
        self._shutdown(emergency=False)

    def abort(self) -> None:
        """Outputs off at once without ramp (exception, signal, exit), stop the loop, close."""
        if self._thread is not None:
            with self._lock:
                self._supervisor.estop()
            self._shutdown(emergency=True)

    def _shutdown(self, emergency: bool) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        indices = [c.index for c in self.configs]
        steps = ["emergency_off"] if emergency else []
        try:
            for operation in steps + ["set_voltage", "output_off"]:
                self._link.query(operation, indices, 0.0 if operation == "set_voltage" else None)
        except (LinkError, ProtocolError):
            if not emergency:
                try:
                    self._link.query("emergency_off", indices)
                except (LinkError, ProtocolError):
                    pass  # the link is gone: the device-side limits and watchdog remain
        finally:
            self._port.close()
            self._remove_exit_guards()

    def __enter__(self):
        return self.open()

    def __exit__(self, exc_type, exc, tb):
        self.abort() if exc_type is not None else self.close()
        return False

    # --- exit guards ---------------------------------------------------------------------------
    def _install_exit_guards(self) -> None:
        ref = weakref.ref(self)
        self._atexit = lambda: (s := ref()) is not None and s.abort()
        atexit.register(self._atexit)
        self._previous_sigterm = None
        if self._handle_signals and threading.current_thread() is threading.main_thread():
            self._previous_sigterm = signal.signal(signal.SIGTERM, self._on_sigterm)

    def _remove_exit_guards(self) -> None:
        atexit.unregister(self._atexit)
        if self._previous_sigterm is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, self._previous_sigterm)
            self._previous_sigterm = None

    def _on_sigterm(self, signum, frame):
        previous = self._previous_sigterm
        self.abort()
        if callable(previous):
            previous(signum, frame)
        else:
            raise SystemExit(128 + signum)

    # --- thread-safe API -----------------------------------------------------------------------
    def _change(self, action):
        with self._lock:
            result = action(self._clock())
        self._wake.set()
        return result

    def enable(self, channel: str) -> None:
        """Switch the output on at 0 V (refused while faults are latched)."""
        self._change(lambda now: self._supervisor.enable(channel, now))

    def disable(self, channel: str) -> None:
        """Ramp to 0 V at the slew limit, then switch the output off."""
        self._change(lambda now: self._supervisor.channel(channel).disable(now))

    def ramp_to(self, channel: str, target_v: float, slew_rate_v_per_s: float | None = None, *,
                token: str) -> RampHandle:
        """Start a smooth ramp for the client holding control (``token`` from `claim_control`); a target above
        the ceiling raises LimitError naming the limit, another client's token ControlError naming the owner."""
        ramp_id = self._change(
            lambda now: self._supervisor.ramp_to(channel, now, target_v, slew_rate_v_per_s, token=token))
        return RampHandle(self, channel, ramp_id, float(target_v))

    def claim_control(self, client: str) -> str:
        """Take control as ``client`` (a name); returns the session token that ramps and heartbeats carry.
        ControlError while another client holds control."""
        return self._change(lambda now: self._supervisor.claim_control(client, now))

    def release_control(self, token: str) -> str:
        """End the control session of ``token``; outputs it left energised ramp to 0 V. Returns the client name."""
        return self._change(lambda now: self._supervisor.release_control(token, now))

    def heartbeat(self, token: str) -> None:
        """Sign of life from the client holding control (ControlError for any other token)."""
        self._change(lambda now: self._supervisor.heartbeat(now, token))

    def set_safe_voltage(self, voltage: float | None) -> None:
        """Assembly safe voltage [V] for every channel (None = unknown)."""
        self._change(lambda now: self._supervisor.set_safe_voltage(voltage))

    def estop(self) -> None:
        """Latch ESTOP: every output to 0 V and off within one cycle."""
        self._change(lambda now: self._supervisor.estop())

    def reset_faults(self, all_channels: bool = False) -> list[str]:
        """Clear the latched faults (device emergency state too) of the faulted channels, or of every channel
        with ``all_channels`` (healthy outputs then ramp down at the device ramp); reset outputs stay off until
        enabled. Returns the names of the channels reset."""
        def reset(now):
            names = self._supervisor.reset(now, all_channels)
            self._reconfigure |= bool(names)
            return names
        return self._change(reset)

    def reset_device(self) -> None:
        """Send ``*RST`` (outputs off, Vset 0, device defaults), then set and read back the device limits
        again; only with every output off. Latched faults stay latched."""
        with self._lock:
            if any(c.output_enabled for c in self._supervisor.channels.values()):
                raise StateError("reset_device: switch every output off first (disable)")
            self._device_reset = self._reconfigure = True
        self._wake.set()

    def snapshot(self) -> SupplySnapshot:
        with self._lock:
            channels = tuple(
                ChannelSnapshot(name=c.config.name, index=c.config.index, setpoint=c.setpoint, target=c.target,
                                measured_voltage=self._measured[name][0], measured_current=self._measured[name][1],
                                ceiling=c.ceiling, output_enabled=c.output_enabled, ramping=c.ramping,
                                faults=c.faults, fault_text=c.fault_text)
                for name, c in self._supervisor.channels.items())
            control = self._supervisor.control
            return SupplySnapshot(self.device_id, self.port_name, self._supervisor.estop_latched,
                                  self._link_error, self._stamp, channels, control.owner or "",
                                  control.heartbeat_age(self._clock()), self._supervisor.heartbeat_timeout_s)

    def wait_outputs_off(self, timeout: float | None = None) -> bool:
        """Block until every output is off (e.g. after `disable`); False if ``timeout`` [s] passed first."""
        with self._cycle_done:
            return self._cycle_done.wait_for(
                lambda: not any(c.output_enabled for c in self._supervisor.channels.values()), timeout)

    def wait_cycles(self, count: int = 1, timeout: float | None = None) -> bool:
        """Block until ``count`` more control cycles have finished."""
        with self._cycle_done:
            goal = self._cycles + count
            return self._cycle_done.wait_for(lambda: self._cycles >= goal, timeout)

    # --- control loop --------------------------------------------------------------------------
    def _run(self) -> None:
        next_cycle = self._clock()
        try:
            while not self._stop.is_set():
                tripped = self._cycle()
                next_cycle += self._period
                delay = next_cycle - self._clock()
                if delay < -self._period:  # fell behind: restart the schedule instead of bursting
                    next_cycle, delay = self._clock(), 0.0
                if tripped or self._wake.wait(max(0.0, delay)):
                    # A new fault or a request (e-stop, ramp): run at once and keep the period from there.
                    self._wake.clear()
                    next_cycle = self._clock()
        except BaseException:
            with self._lock:
                self._supervisor.trip_all(Fault.DEVICE, "control loop crashed")
            self._stop.set()
            self._safe_off_from_loop()
            raise

    def _safe_off_from_loop(self) -> None:
        try:
            self._link.query("emergency_off", [c.index for c in self.configs])
        except (LinkError, ProtocolError):
            pass

    def _cycle(self) -> bool:
        """One control cycle; True when a new fault latched (the next cycle then runs at once)."""
        with self._lock:
            self._stamp = self._clock()
            commands = self._supervisor.step(self._stamp)
            stepped = {n: (c.ramp_id, c.ramping, c.setpoint) for n, c in self._supervisor.channels.items()}
            reconfigure, self._reconfigure = self._reconfigure, False
            device_reset, self._device_reset = self._device_reset, False
            faults_before = {n: c.faults for n, c in self._supervisor.channels.items()}
        try:
            if device_reset:
                self._link.query("reset")
                self._sent = {c.name: _Sent() for c in self.configs}  # latched faults cut again below
            if reconfigure:
                self._configure_device()
            self._emergency_off([c for c in self.configs
                                 if commands[c.name].emergency_off and not self._sent[c.name].emergency])
            for config in self.configs:
                if not commands[config.name].emergency_off:
                    self._apply(config, commands[config.name])
            indices = [c.index for c in self.configs]
            voltages = self._link.query("measure_voltage", indices)
            currents = self._link.query("measure_current", indices)
            statuses = self._link.query("read_status", indices)
            events = self._link.query("read_event_status", indices)
        except (LinkError, ProtocolError, ConfigurationError) as error:
            with self._cycle_done:
                self._supervisor.link_failed(self._clock())
                self._link_error = str(error)
                self._reconfigure |= reconfigure
                self._device_reset |= device_reset
                self._cycles += 1
                self._cycle_done.notify_all()
            return False
        with self._cycle_done:
            now = self._clock()
            self._supervisor.link_ok(now)
            self._link_error = ""
            for config, voltage, current, status, event in zip(self.configs, voltages, currents, statuses, events):
                report = self.dialect.status_report(status, event)
                sent = self._sent[config.name]
                fault, over_current = None, False
                if not sent.emergency:  # after our own emergency off the device flags are expected
                    fault, over_current = report.fault, report.over_current
                    if fault is None and sent.output_on != report.output_on:
                        fault = "supply output " + ("off although commanded on (reset or interlock)"
                                                    if sent.output_on else "on although commanded off")
                self._supervisor.channel(config.name).observe(now, voltage, current, fault, over_current)
                self._measured[config.name] = (voltage, current)
                ramp_id, ramping, setpoint = stepped[config.name]
                self._applied[config.name] = _Applied(ramp_id, ramping,
                                                      abs(voltage - setpoint) <= config.mismatch_tolerance_v)
            self._cycles += 1
            self._cycle_done.notify_all()
            return any(c.faults != faults_before[n] for n, c in self._supervisor.channels.items())

    def _emergency_off(self, configs: list[ChannelConfig]) -> None:
        """Cut the outputs of every newly faulted channel in one line (retried each cycle until acknowledged)."""
        if configs:
            indices = [c.index for c in configs]
            self._link.query("emergency_off", indices)
            for config in configs:
                self._sent[config.name] = _Sent(0.0, False, True)
            self._link.query("set_voltage", indices, 0.0)

    def _apply(self, config: ChannelConfig, command: ChannelCommand) -> None:
        """Send what changed on one channel since the last cycle."""
        sent, ch = self._sent[config.name], [config.index]
        if sent.emergency:  # faults were reset: release the device's latched emergency off
            self._link.query("emergency_clear", ch)
            self._link.query("clear_events", ch)
            sent.emergency = False
        if command.output_on and not sent.output_on:
            self._link.query("set_voltage", ch, 0.0)
            self._link.query("output_on", ch)
            sent.setpoint, sent.output_on = 0.0, True
        if command.output_on and command.setpoint != sent.setpoint:
            self._link.query("set_voltage", ch, command.setpoint)
            sent.setpoint = command.setpoint
        if not command.output_on and sent.output_on:
            self._link.query("set_voltage", ch, 0.0)
            self._link.query("output_off", ch)
            sent.setpoint, sent.output_on = 0.0, False
