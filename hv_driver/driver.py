"""HvSupply: owns the serial links of one or more supplies, runs the supervised control loop in its own thread (or,
on a simulated clock, stepped by its caller: `hv_driver.clock`).

Thread model: one loop thread does all serial I/O; the public methods (thread-safe) only change the supervisor's
state under a lock and wake the loop, which applies the change within one cycle. Each supply (one port, a
`Device`) is served in turn every cycle; a failing link trips only the channels on it. What is sent to a supply
is chosen from its dialect's capabilities (device.py); nothing here depends on one dialect.
"""
import atexit
import logging
import math
import signal
import statistics
import threading
import weakref
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .clock import SimulatedClock, as_clock
from .config import ChannelConfig
from .control import pulse_command
from .device import ConfigurationError, Device
from .dialects import CurrentSensing, Dialect, IsegEdcp, ProtocolError
from .errors import SettingError, StateError
from .events import SupervisorEvent
from .faults import Fault
from .link import LinkError
from .pulse import PulseTally, PulseTrain, plan_pulse_train
from .supervisor import DEFAULT_HEARTBEAT_TIMEOUT_S, DEFAULT_LOOP_RATE_HZ, IMMEDIATE_FAULTS, Supervisor

log = logging.getLogger(__name__)

# The longest a wait without a timeout runs the loop on a simulated clock [s]: the longest ramp a request may take.
MAX_SIMULATED_WAIT_S = 600.0
# The longest the loop waits for the reader of its client's channel to take in one more message before it judges the
# client silent anyway [s] (`listen`): a stuck reader must not hold the loop; it waits so once per lapse at most.
TAKE_IN_PATIENCE_S = 0.05
# How many recent cycles tell the period the loop sustains (their median): a line slower than the loop rate sets it in
# that many cycles, while one stall among them does not (the supervisor discounts a stall in this unit).
SUSTAINED_PERIOD_CYCLES = 15


@dataclass(frozen=True)
class ChannelSnapshot:
    name: str
    index: int
    setpoint: float            # [V] commanded to the supply
    target: float              # [V] end of the running ramp
    measured_voltage: float    # [V]
    measured_current: float    # [A]; NaN on a supply without current readback
    ceiling: float             # [V]
    output_enabled: bool
    ramping: bool
    faults: Fault
    fault_text: str
    port: str = ""             # the port of the channel's supply


@dataclass(frozen=True)
class SupplySnapshot:
    device_id: str             # identification of each supply, "; "-separated
    port: str                  # port of each supply, ", "-separated
    estop: bool
    link_error: str            # last failed exchange of any supply, "" when the last ones succeeded
    stamp: float               # clock time [s] of the last control cycle's setpoints
    channels: tuple[ChannelSnapshot, ...]
    controller: str = ""       # name of the client holding control, "" when none
    heartbeat_age_s: float | None = None  # since the controlling client's last sign of life
    heartbeat_timeout_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S  # inf = watchdog off
    control_ended: str = ""    # why the last control session ended, e.g. "control of 'demo' lapsed: ..."

    def channel(self, name: str) -> ChannelSnapshot:
        return next(c for c in self.channels if c.name == name)


@dataclass(frozen=True)
class _Applied:
    """Ramp state of one channel as of the last cycle whose commands reached the device."""

    ramp_id: int = 0
    ramping: bool = False
    settled: bool = True  # the readback of that cycle within the mismatch tolerance of the setpoint


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
        return self._supply.wait_for(lambda: self._state()[1], timeout)

    def cancel(self) -> "RampHandle | None":
        """Ramp the channel back to 0 V if this ramp is still the running one; returns that ramp."""
        down = None
        with self._supply._lock:
            ch = self._supply._supervisor.channel(self.channel)
            if ch.ramp_id == self._ramp_id and not ch.faults and ch.output_enabled:
                down = RampHandle(self._supply, self.channel, ch.ramp_to(self._supply._clock(), 0.0), 0.0)
        self._supply._wake.set()
        return down


class PulseHandle:
    """A running pulse train on one or more channels: ``wait``, ``done``, ``cancel`` (back to 0 V), ``cycles_done``
    (as the device counted them where it switches the train, else periods begun on the driver's clock),
    ``frequency`` (as the device quantised it, or as generated)."""

    def __init__(self, supply: "HvSupply", trains: dict[str, PulseTrain], ramp_ids: dict[str, int]):
        self._supply, self.trains, self._ramp_ids = supply, trains, ramp_ids
        self._channels = [RampHandle(supply, name, ramp_ids[name], trains[name].end) for name in trains]
        self.generated_by = "device" if next(iter(trains.values())).on_device else "loop"
        self._ended_at: float | None = None
        self._failure: str | None = None  # why it failed, as it stood before the others were stopped

    def _ended(self) -> bool:
        """Every channel's train is over, or one ended without completing (fault, superseded)."""
        states = [(channel, channel._state()[1]) for channel in self._channels]
        return all(done for _, done in states) or any(done and not c.succeeded for c, done in states)

    @property
    def done(self) -> bool:
        with self._supply._lock:
            return self._ended()

    def _tallies(self) -> dict[str, PulseTally]:
        """Per channel of a streamed train: its `PulseTally` (none for a train the device switches)."""
        with self._supply._lock:
            tallies = {name: self._supply._supervisor.channel(name).pulse_tally for name in self.trains}
            return {name: tally for name, tally in tallies.items()
                    if tally is not None and tally.ramp_id == self._ramp_ids[name]}

    def _ended_by_host(self) -> dict[str, tuple[int, int] | None]:
        """Per channel of a train the device switches that the host ended by its fallback, its count never reaching
        the total: the count as the device last reported it (None: never)."""
        with self._supply._lock:
            ended = {name for name, train in self.trains.items()
                     if self._supply._supervisor.channel(name).ended_by_host is train}
            return {name: sent.counted for device in self._supply._devices
                    for name, sent in device.sent.items() if name in ended}

    @property
    def short_pulses(self) -> dict[str, int]:
        """Per channel of a streamed train: pulses that fell short of the amplitude (see `PulseTally`)."""
        return {name: tally.short for name, tally in self._tallies().items()}

    @property
    def message(self) -> str:
        """Why it ended ("" while it runs): the channels that did not complete or whose pulses fell short, else
        "completed"."""
        if not self.done:
            return ""
        if self._failure is not None:
            return self._failure
        failed = [f"{c.channel}: {c.message}" for c in self._channels if c.done and not c.succeeded]
        train = next(iter(self.trains.values()))
        failed += [f"{name}: {tally.short} of {train.cycles} pulses fell short of {train.amplitude:g} V (the control "
                   f"loop fell behind, its longest gap between cycles {tally.longest_gap * 1e3:.0f} ms; slew-limited, "
                   f"it does not catch up)" for name, tally in self._tallies().items() if tally.short]
        failed += [f"{name}: not completed: the board counted "
                   f"{'no cycle' if counted is None else f'{counted[0]} of {counted[1]} cycles'}, so the host ended "
                   f"the train by its own clock (fallback)" for name, counted in self._ended_by_host().items()]
        return "; ".join(failed) if failed else f"completed {self.cycles_done} cycles"

    @property
    def succeeded(self) -> bool:
        return (self.done and all(channel.succeeded for channel in self._channels)
                and not any(self.short_pulses.values()) and not self._ended_by_host())

    @property
    def cycles_done(self) -> int:
        with self._supply._lock:
            counted = [d.sent[n].counted for d in self._supply._devices for n in self.trains
                       if n in d.sent and d.sent[n].armed is self.trains[n]]
        if counted and all(count is not None for count in counted):  # the device's own count (QCycle)
            return min(done for done, _ in counted)
        if self._ended_at is None and self.done:
            self._ended_at = self._supply._clock()
        at = self._supply._clock() if self._ended_at is None else self._ended_at
        return min(train.cycles_done(at) for train in self.trains.values())

    @property
    def frequency(self) -> float:
        """[Hz] the device's quantised frequency once it is armed (square), else the requested one."""
        with self._supply._lock:
            answered = [d.sent[n].frequency for d in self._supply._devices for n in self.trains
                        if n in d.sent and d.sent[n].armed is self.trains[n]]
        return answered[0] if answered else next(iter(self.trains.values())).frequency

    def wait(self, timeout: float | None = None) -> bool:
        """Block until every channel's train ends or ``timeout`` [s] passes; True when they ended."""
        ended = self._supply.wait_for(self._ended, timeout)
        if ended and not self.succeeded and self._failure is None:  # the others stop too (one train, one outcome)
            self._failure = self.message
            for channel in self._channels:
                if not channel.done:
                    channel.cancel()
        return ended

    def cancel(self) -> None:
        """Stop the train: each channel still running it goes back to 0 V (square: at once; smooth: ramped); the
        handle then follows those ramps down."""
        self._channels = [channel.cancel() or channel for channel in self._channels]


class HvSupply:
    """One or more HV supplies behind the safety supervisor.

    port: pyserial URL or device path of the supply (a pty path for the simulated supply), or a list of them, one
        per supply (e.g. one single-channel board per leg); a channel's ``device`` is its supply's position in it.
    dialect: the supplies' dialect (all of one kind); default iseg EDCP.
    channels: one ChannelConfig per output used.
    loop_rate_hz: control loop rate; each cycle sends new setpoints and reads voltage, current
        and status of every channel.
    link_timeout_s: no valid reply from a supply for this long trips LINK on its channels.
    heartbeat_timeout_s: the client holding control (`claim_control`) must call `heartbeat(token)` (or
        ramp) this often, or its control lapses and its energised outputs ramp to 0 V (HEARTBEAT).
        math.inf switches the watchdog off on purpose; the driver then warns at every `open()`.
    reply_timeout_s: time allowed for one answer (default: a quarter of link_timeout_s).
    expected_identity: text each device's identification (``*IDN?``) must contain, e.g. its model, checked at
        `open`; "" checks nothing.
    clock: the loop's time (`hv_driver.clock`; default the machine's monotonic clock, a bare callable is read as
        one). With a `SimulatedClock` no thread runs: `step` / `run_for` advance the loop period by period, and
        every wait (`RampHandle.wait`, `wait_cycles`, ...) runs the loop until it ends; each port is then a
        pyserial-like object on the same clock (e.g. `sim_fallback.memory_port.MemoryPort`).
    """

    def __init__(self, port: str | Sequence[str], baudrate: int | None = None, channels: list[ChannelConfig] = (),
                 loop_rate_hz: float = DEFAULT_LOOP_RATE_HZ, link_timeout_s: float = 0.5,
                 heartbeat_timeout_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S, reply_timeout_s: float | None = None,
                 dialect: Dialect | None = None, handle_signals: bool = True, clock=None,
                 expected_identity: str = ""):
        if not (math.isfinite(loop_rate_hz) and 1.0 <= loop_rate_hz <= 1000.0):
            raise SettingError(f"loop_rate_hz={loop_rate_hz!r}: between 1 and 1000")
        reply_timeout_s = link_timeout_s / 4 if reply_timeout_s is None else reply_timeout_s
        if not (math.isfinite(reply_timeout_s) and 0 < reply_timeout_s < link_timeout_s):
            raise SettingError(f"reply_timeout_s={reply_timeout_s!r}: > 0 and below link_timeout_s")
        ports = [port] if isinstance(port, str) or not isinstance(port, Sequence) else list(port)
        self.configs = list(channels)
        for config in self.configs:
            if config.device >= len(ports):
                raise SettingError(f"channel {config.name!r}: device={config.device}, but only {len(ports)} port(s) "
                                   f"are given: {ports}")
        self._clock = clock = as_clock(clock)
        self._simulated = isinstance(clock, SimulatedClock)
        self.expected_identity = expected_identity
        self.dialect = dialect or IsegEdcp()
        self._period = 1.0 / loop_rate_hz
        self._supervisor = Supervisor(self.configs, link_timeout_s=link_timeout_s,
                                      heartbeat_timeout_s=heartbeat_timeout_s, nominal_period_s=self._period,
                                      now=clock())
        self._devices = [Device(name, baudrate, self.dialect, [c for c in self.configs if c.device == k],
                                reply_timeout_s, clock) for k, name in enumerate(ports)]
        self.port_name = ", ".join(device.port_name for device in self._devices)
        self._link_timeout = link_timeout_s
        self._handle_signals = handle_signals
        self._lock = threading.RLock()
        self._cycle_done = threading.Condition(self._lock)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._running = False  # open: the loop runs (its thread, or stepped on a simulated clock)
        self._next_cycle = 0.0  # the loop's next slot on its schedule
        self._measured = {c.name: (0.0, 0.0) for c in self.configs}
        self._device_on = dict.fromkeys(self._measured, False)  # the output as the device last reported it
        self._applied = {c.name: _Applied() for c in self.configs}
        self._reconfigure = self._device_reset = False
        self._cycles = 0
        self._cycle_durations: deque[float] = deque(maxlen=SUSTAINED_PERIOD_CYCLES)
        self._stamp = clock()
        self._next_start: float | None = None  # start of the next train a supply switches, if one is armed
        self._take_in: Callable[[float], None] | None = None  # see `listen`

    @property
    def device_id(self) -> str:
        return "; ".join(device.device_id for device in self._devices)

    # --- lifecycle -----------------------------------------------------------------------------
    def open(self) -> "HvSupply":
        """Open every port, identify each supply, set and read back its limits, start the loop."""
        opened = []
        try:
            for device in self._devices:
                device.open_port()
                opened.append(device)
                self._start_session(device)
        except (LinkError, ProtocolError, ConfigurationError):
            for device in opened:
                device.close_port()
            raise
        if self._supervisor.heartbeat_watchdog_off:
            log.warning("heartbeat watchdog OFF (heartbeat_timeout_s=inf) on %s: energised outputs stay on "
                        "when the controlling client dies", self.port_name)
        for k, _ in enumerate(self._devices):
            self._supervisor.link_ok(self._clock(), k)
        self._stop.clear()
        self._running = True
        self._next_cycle = self._clock()
        if not self._simulated:
            self._thread = threading.Thread(target=self._run, name=f"hv-loop {self.port_name}", daemon=True)
            self._thread.start()
        self._install_exit_guards()
        return self

    def _start_session(self, device: Device) -> None:
        """Identify, check the channels, switch every output off, configure the device side and take in what an
        earlier session left (outputs still up, latched device faults). The steps are repeated while answers keep
        failing, for up to link_timeout_s (the link watchdog's rule: a supply still starting up, e.g. a simulator
        on a loaded host, is not a dead one)."""
        failing_since = None
        while True:
            try:
                device.identify(self.expected_identity)
                device.switch_all_off()
                self._configure(device)
                found = device.found()
                break
            except (LinkError, ProtocolError):
                failing_since = self._clock() if failing_since is None else failing_since
                if self._clock() - failing_since > self._link_timeout:
                    raise
        with self._lock:
            for name, (voltage, report) in found.items():
                channel = self._supervisor.channel(name)
                channel.output_found(self._clock(), voltage)
                if report.fault:  # a latched device fault survives reconnects until reset on purpose
                    channel.trip(Fault.DEVICE, report.fault)
                    device.sent[name].emergency = True
                    device.sent[name].cut_confirmed = not report.output_on  # else cut in the first cycle

    def _configure(self, device: Device) -> None:
        """Device-side second line of defence, read back; the supervisor learns the supply's limit and ramp."""
        sides = device.configure()
        with self._lock:
            for name, side in sides.items():
                channel = self._supervisor.channel(name)
                channel.set_device_limit(side.voltage_limit)
                channel.set_device_ramp(side.ramp_rate_v_per_s)  # outputs move, and ramp down when off, at it
                # Without current readback a breakdown shows only as the voltage collapsing.
                channel.breakdown_guard = device.capabilities.current is CurrentSensing.NONE

    def close(self, ramp_down_timeout: float = 5.0) -> None:
        """Ramp every output to 0 V and switch it off, stop the loop, close the ports."""
        if not self._running:
            return
        for name in self._supervisor.channels:
            self.disable(name)
        self.wait_outputs_off(ramp_down_timeout)
        self._shutdown(emergency=False)

    def abort(self) -> None:
        """Outputs off at once without ramp (exception, signal, exit), stop the loop, close."""
        if self._running:
            with self._lock:
                self._supervisor.estop()
            self._shutdown(emergency=True)

    def _shutdown(self, emergency: bool) -> None:
        self._stop.set()
        self._wake.set()
        self._running = False
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        try:
            for device in self._devices:
                device.shut_down(emergency)
        finally:
            for device in self._devices:
                device.close_port()
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
    def _change(self, action, wake: bool = True):
        """``action(now)`` under the loop's lock; ``wake``: the loop applies it in a cycle at once (a change of what
        is commanded), not at its next slot."""
        with self._lock:
            result = action(self._clock())
        if wake:
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

    def pulse(self, channels: Sequence[str], amplitude_v: float, frequency_hz: float, duty: float = 0.5,
              phase: float = 0.0, cycles: int = 1, edge: str = "smooth", slew_rate_v_per_s: float | None = None, *,
              token: str) -> "PulseHandle":
        """Switch ``channels`` together between 0 V and ``amplitude_v``, ``cycles`` periods at ``frequency_hz``,
        on for ``duty`` of each period, the on-edges delayed by ``phase`` of a period on a time grid shared by
        every train of that frequency. ``edge`` "square": the device switches itself (supplies with device-side
        switching); "smooth": minimum-jerk edges at ``slew_rate_v_per_s`` (None: the configured slew limit),
        generated in this loop. What the supply cannot produce raises PulseLimitError naming the limit, before
        anything changes (all channels or none); the control claim applies as for `ramp_to`."""
        def plan(config, now):
            return plan_pulse_train(config, self.dialect.capabilities, self.dialect.name, now, self._period,
                                    amplitude_v, frequency_hz, duty, phase, cycles, edge, slew_rate_v_per_s)
        command = pulse_command(channels, amplitude_v, frequency_hz, duty, phase, cycles, edge, slew_rate_v_per_s)
        trains, ramp_ids = self._change(
            lambda now: self._supervisor.pulse(list(channels), now, plan, token=token, command=command))
        return PulseHandle(self, trains, ramp_ids)

    def claim_control(self, client: str, nonce: str = "") -> str:
        """Take control as ``client`` (a name); returns the session token that signs ramps and heartbeats
        (`hv_driver.control`). ControlError while another client holds control; ``nonce``: `ControlClaim.claim`."""
        return self._change(lambda now: self._supervisor.claim_control(client, now, nonce))

    def release_control(self, token: str) -> str:
        """End the control session of ``token``; outputs it left energised ramp to 0 V. Returns the client name."""
        return self._change(lambda now: self._supervisor.release_control(token, now))

    def heartbeat(self, token: str, sent: float | None = None) -> None:
        """Sign of life from the client holding control (ControlError for any other token), sent at ``sent`` on
        this supply's clock (default: now; see `listen`). It changes no command, so it does not wake the loop."""
        self._change(lambda now: self._supervisor.heartbeat(now, token, sent), wake=False)

    def listen(self, take_in: Callable[[float], None] | None) -> None:
        """Hear the controlling client through a channel (`hv_driver.server`): before the loop judges the client
        silent it calls ``take_in(patience)``, which returns once what the client sent before then has been taken in
        (each heartbeat with its ``sent`` stamp), or once the channel's reader has taken in nothing for ``patience``
        [s] (TAKE_IN_PATIENCE_S), so a stall of this process does not count as the client's silence. None: the client
        calls in directly."""
        self._take_in = take_in

    def node_lost(self, reason: str) -> None:
        """The node driving this supply is gone (see `hv_driver.server`): control ends, every channel latches
        NODE_LOST and energised outputs ramp to 0 V."""
        self._change(lambda now: self._supervisor.node_lost(now, reason))

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
        """Send each supply's own reset (outputs off, Vset 0, device defaults), then set and read back the device
        limits again; only with every output off, and only on supplies that have a reset. Latched faults stay."""
        without = [d.port_name for d in self._devices if not d.has("reset")]
        if without:
            raise StateError(f"reset_device: the {self.dialect.name} supply has no reset command ({without})")
        with self._lock:
            if any(c.output_enabled for c in self._supervisor.channels.values()):
                raise StateError("reset_device: switch every output off first (disable)")
            self._device_reset = self._reconfigure = True
        self._wake.set()

    def drain_events(self) -> list[SupervisorEvent]:
        """The supervisor's events since the last drain, oldest first (hv_driver.events)."""
        with self._lock:
            return self._supervisor.events.drain()

    def snapshot(self) -> SupplySnapshot:
        with self._lock:
            ports = {c.name: self._devices[c.device].port_name for c in self.configs}
            channels = tuple(
                ChannelSnapshot(name=c.config.name, index=c.config.index, setpoint=c.setpoint, target=c.target,
                                measured_voltage=self._measured[name][0], measured_current=self._measured[name][1],
                                ceiling=c.ceiling, output_enabled=self._output_on(name, c), ramping=c.ramping,
                                faults=c.faults, fault_text=c.fault_text, port=ports[name])
                for name, c in self._supervisor.channels.items())
            control = self._supervisor.control
            link_error = "; ".join(d.link_error for d in self._devices if d.link_error)
            return SupplySnapshot(self.device_id, self.port_name, self._supervisor.estop_latched,
                                  link_error, self._stamp, channels, control.owner or "",
                                  control.heartbeat_age(self._clock()), self._supervisor.heartbeat_timeout_s,
                                  control.ended)

    def _output_on(self, name: str, channel) -> bool:
        """On as commanded, or as the device last reported it, or cut without the device confirming it: a snapshot
        never claims off an output the device may still hold on."""
        sent = self._devices[channel.config.device].sent[name]
        return channel.output_enabled or self._device_on[name] or (sent.emergency and not sent.cut_confirmed)

    def wait_outputs_off(self, timeout: float | None = None) -> bool:
        """Block until every output is off (e.g. after `disable`); False if ``timeout`` [s] passed first."""
        return self.wait_for(lambda: not any(c.output_enabled for c in self._supervisor.channels.values()), timeout)

    def wait_cycles(self, count: int = 1, timeout: float | None = None) -> bool:
        """Block until ``count`` more control cycles have finished."""
        goal = self._cycles + count
        return self.wait_for(lambda: self._cycles >= goal, timeout)

    def wait_for(self, predicate, timeout: float | None = None) -> bool:
        """Block until ``predicate()`` holds (checked under the loop's lock after each cycle) or ``timeout`` [s]
        passes; True when it held. On a simulated clock this runs the loop (no timeout: up to MAX_SIMULATED_WAIT_S
        of simulated time)."""
        if not self._simulated:
            with self._cycle_done:
                return self._cycle_done.wait_for(predicate, timeout)
        end = self._clock() + (MAX_SIMULATED_WAIT_S if timeout is None else timeout)
        while True:
            with self._lock:
                if predicate():
                    return True
            if not self._running or self._clock() >= end:
                return False
            self.step()

    # --- simulated time ------------------------------------------------------------------------
    def step(self) -> None:
        """Run one control cycle, then advance the simulated clock to the next one on the loop's schedule (none on
        a request or a new fault: the loop runs again at once, as its thread does). Simulated clock only."""
        if not self._simulated:
            raise StateError("step: the loop runs in its own thread (only an HvSupply on a SimulatedClock is stepped)")
        if not self._running:
            raise StateError("step: the supply is not open")
        try:
            tripped = self._cycle()
        except BaseException:
            self._crashed()
            raise
        self._next_cycle, delay = self._schedule(self._next_cycle)
        if tripped or self._wake.is_set():
            self._wake.clear()
            self._next_cycle = self._clock()
        else:
            self._clock.advance(delay)

    def run_for(self, seconds: float) -> None:
        """Run the loop for ``seconds`` of simulated time (period by period, as `step`)."""
        end = self._clock() + seconds
        while self._running and self._clock() < end:
            self.step()

    # --- control loop --------------------------------------------------------------------------
    def _schedule(self, next_cycle: float) -> tuple[float, float]:
        """After a cycle: the slot of the next one and the wait [s] until it."""
        next_cycle += self._period
        delay = next_cycle - self._clock()
        if delay < -self._period:  # fell behind: restart the schedule instead of bursting
            next_cycle, delay = self._clock(), 0.0
        if self._next_start is not None:  # a train the supply switches starts on time, not on the grid
            delay = min(delay, self._next_start - self._clock())
        return next_cycle, max(0.0, delay)

    def _run(self) -> None:
        next_cycle = self._clock()
        try:
            while not self._stop.is_set():
                tripped = self._cycle()
                next_cycle, delay = self._schedule(next_cycle)
                if tripped or self._wake.wait(delay):
                    # A new fault or a request (e-stop, ramp): run at once and keep the period from there.
                    self._wake.clear()
                    next_cycle = self._clock()
        except BaseException:
            self._crashed()
            raise

    def _crashed(self) -> None:
        with self._lock:
            self._supervisor.trip_all(Fault.DEVICE, "control loop crashed")
        self._stop.set()
        self._safe_off_from_loop()

    def _safe_off_from_loop(self) -> None:
        for device in self._devices:
            try:
                device.cut(device.configs)
            except (LinkError, ProtocolError):
                pass

    def _cut_at_once(self, k: int, device: Device, configs: list[ChannelConfig]) -> None:
        """Cut the channels whose fault this cycle's readback showed, in this cycle (the next one sends the cut again
        until the supply confirms it)."""
        try:
            device.cut(configs)
        except (LinkError, ProtocolError) as error:
            with self._lock:
                self._supervisor.link_failed(self._clock(), k)
                device.link_error = str(error)

    def _start_due_trains(self, pulses: dict) -> None:
        """Start every armed train the supplies switch whose start has come, before any other exchange."""
        for device in self._devices:
            try:
                device.start_due_trains(pulses, self._clock())
            except (LinkError, ProtocolError):
                pass  # retried by apply, where a failure counts against the link

    def _cycle(self) -> bool:
        """One control cycle; True when a new fault latched (the next cycle then runs at once). A fault read back
        from a supply is cut at once, before the next supply's exchanges."""
        now = started = self._clock()
        if self._take_in is not None:
            with self._lock:
                lapsing = self._supervisor.control.silent(now)
            if lapsing:  # what the client sent before now is heard before its silence is judged
                self._take_in(TAKE_IN_PATIENCE_S)
        with self._lock:
            self._stamp = now
            commands = self._supervisor.step(self._stamp)
            stepped = {n: (c.ramp_id, c.ramping, c.setpoint) for n, c in self._supervisor.channels.items()}
            reconfigure, self._reconfigure = self._reconfigure, False
            device_reset, self._device_reset = self._device_reset, False
            faults_before = {n: c.faults for n, c in self._supervisor.channels.items()}
        pulses = {name: c.pulse for name, c in commands.items() if c.output_on and not c.emergency_off}
        self._next_start = min((t.start for t in pulses.values() if t is not None and t.start > self._stamp),
                               default=None)
        for k, device in enumerate(self._devices):
            self._start_due_trains(pulses)  # between the supplies' exchanges too: a slow cycle delays no start
            try:
                if device_reset:
                    device.reset()  # latched faults are cut again below
                if reconfigure:
                    self._configure(device)
                device.cut(device.unconfirmed_cuts({n for n, c in commands.items() if c.emergency_off}))
                for config in device.configs:
                    command = commands[config.name]
                    if not command.emergency_off:
                        device.apply(config, command.setpoint, command.output_on, command.pulse, self._clock())
                readings = device.read()
            except (LinkError, ProtocolError, ConfigurationError) as error:
                with self._lock:
                    self._supervisor.link_failed(self._clock(), k)
                    device.link_error = str(error)
                    self._reconfigure |= reconfigure
                    self._device_reset |= device_reset
                continue
            with self._lock:
                now = self._clock()
                self._supervisor.link_ok(now, k)
                device.link_error = ""
                for config in device.configs:
                    reading, sent = readings[config.name], device.sent[config.name]
                    fault, over_current = None, False
                    self._device_on[config.name] = reading.report.output_on
                    if sent.emergency:  # after our own cut the device flags are expected, its output off
                        if device.confirm_cut(config, reading):
                            self._supervisor.channel(config.name).trip(
                                Fault.CUT_UNCONFIRMED, f"after the cut the supply reports its output on (measured "
                                                       f"{reading.voltage:.0f} V); cut again every cycle until it "
                                                       f"reports it off")
                    else:
                        fault, over_current = reading.report.fault, reading.report.over_current
                        # An output the device cut for over-current is explained by that fault.
                        if (fault is None and not over_current and sent.output_on != reading.report.output_on
                                and not device.count_ended(config)):
                            fault = "supply output " + ("off although commanded on (reset or interlock)"
                                                        if sent.output_on else "on although commanded off")
                    channel = self._supervisor.channel(config.name)
                    if device.count_ended(config):
                        channel.device_count_ended(sent.pulse)
                    channel.observe(reading.measured_at, reading.voltage, reading.current, fault, over_current)
                    current = math.nan if reading.current is None else reading.current
                    self._measured[config.name] = (reading.voltage, current)
                    ramp_id, ramping, setpoint = stepped[config.name]
                    self._applied[config.name] = _Applied(ramp_id, ramping,
                                                          abs(reading.voltage - setpoint) <= config.mismatch_tolerance_v)
                tripped = [c for c in device.configs if self._supervisor.channel(c.name).faults & IMMEDIATE_FAULTS
                           and not device.sent[c.name].emergency]
            self._cut_at_once(k, device, tripped)
        self._cycle_durations.append(self._clock() - started)
        with self._cycle_done:
            self._supervisor.set_cycle_period(max(self._period, statistics.median(self._cycle_durations)))
            self._cycles += 1
            self._cycle_done.notify_all()
            return any(c.faults != faults_before[n] for n, c in self._supervisor.channels.items())
