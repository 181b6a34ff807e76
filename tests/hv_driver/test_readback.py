"""The readback check against a device that ramps: loop stalls, outputs switched off, outputs left on.

A supply with a ramp of its own moves its output towards each command at that rate (`:VOLT OFF` ramps
down at it too). The device model below does that; readbacks are taken shortly after each setpoint,
as the driver's loop does."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hv_driver import ChannelConfig, Fault
from hv_driver.supervisor import SLEW_CREDIT_PERIODS, ChannelSupervisor

pytestmark = pytest.mark.fast

PERIOD = 0.01  # [s] the loop's nominal period in these tests, which step it every 10 ms
GAIT = ChannelConfig("leg", 0, max_voltage_v=3000.0, slew_rate_v_per_s=16000.0)  # the legged gait's 16 kV/s
DEVICE_MARGIN = 1.2  # the driver sets the device ramp to 1.2 x the slew limit


def follow(voltage: float, command: float, rate: float | None, dt: float) -> float:
    """A device output after ``dt`` [s] moving towards ``command`` at ``rate`` [V/s] (None: at once)."""
    if rate is None:
        return command
    reach = rate * dt
    return voltage + max(-reach, min(reach, command - voltage))


class Rig:
    """One channel supervisor driving a device model; readbacks ``delay`` s after each step."""

    def __init__(self, channel: ChannelSupervisor, device_rate: float | None, delay: float = 0.001,
                 voltage: float = 0.0):
        self.channel, self.rate, self.delay = channel, device_rate, delay
        self.t, self.voltage, self.command = 0.0, voltage, 0.0

    def cycle(self, interval: float, measured: float | None = None, noise: float = 0.0):
        """The loop runs ``interval`` s after the last cycle: step, send, read back (``measured``: a stuck
        readback instead of the device's, ``noise``: added to the device's)."""
        self.voltage = follow(self.voltage, self.command, self.rate, interval)
        self.t += interval
        command = self.channel.step(self.t)
        self.command = command.setpoint
        if command.emergency_off:
            self.voltage = 0.0
        readback = follow(self.voltage, self.command, self.rate, self.delay) + noise
        self.channel.observe(self.t + self.delay, readback if measured is None else measured, 1e-7)
        return command


def test_a_loop_stall_at_16_kv_per_s_is_no_readback_mismatch():
    """The CI failure: one 20 ms cycle, then a 550 ms stall, mid-ramp at 16 kV/s."""
    channel = ChannelSupervisor(GAIT, nominal_period_s=PERIOD)
    channel.enable()
    rig = Rig(channel, DEVICE_MARGIN * GAIT.slew_rate_v_per_s)
    channel.ramp_to(0.0, 2400.0)
    for _ in range(12):
        rig.cycle(0.01)
    rig.cycle(0.02)
    rig.cycle(0.55)
    for _ in range(100):
        rig.cycle(0.01)
    assert not channel.faults, channel.fault_text
    assert channel.setpoint == 2400.0


def test_a_stalled_loop_catches_up_by_at_most_two_nominal_periods_of_slew():
    channel = ChannelSupervisor(GAIT, nominal_period_s=PERIOD)
    channel.enable()
    channel.ramp_to(0.0, 2400.0)
    before = channel.step(0.1).setpoint
    after = channel.step(0.65).setpoint  # 550 ms later
    assert after - before == pytest.approx(GAIT.slew_rate_v_per_s * SLEW_CREDIT_PERIODS * 0.01)


GRIPPER = ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=1000.0)  # device ramp 1200 V/s


def held_at_2400_volts() -> tuple[ChannelSupervisor, Rig]:
    """A healthy channel of a supply ramping at 1.2 kV/s, held at 2.4 kV."""
    channel = ChannelSupervisor(GRIPPER, nominal_period_s=PERIOD)
    channel.set_device_ramp(1200.0)
    channel.enable()
    rig = Rig(channel, 1200.0)
    channel.ramp_to(0.0, 2400.0)
    for _ in range(500):
        rig.cycle(0.01)
    assert channel.setpoint == 2400.0 and not channel.faults
    return channel, rig


def test_an_output_switched_off_may_ramp_down_at_the_device_rate():
    channel, rig = held_at_2400_volts()
    channel.reset()  # as reset_faults(all_channels=True): `:VOLT 0`, `:VOLT OFF`; the device ramps down
    voltages = []
    for _ in range(300):
        rig.cycle(0.01)
        voltages.append(rig.voltage)
    assert not channel.faults, channel.fault_text
    assert voltages[50] == pytest.approx(2400.0 - 1200.0 * 0.5) and voltages[-1] == 0.0  # 1.2 kV/s, 0.5 s


def test_an_output_that_does_not_fall_after_off_is_a_mismatch():
    channel, rig = held_at_2400_volts()
    channel.reset()
    cycles = 0
    while not channel.faults and cycles < 200:
        rig.cycle(0.01, measured=2400.0)  # stuck
        cycles += 1
    assert channel.faults == Fault.READBACK_MISMATCH
    # 100 V of tolerance at 1200 V/s, then 0.5 s of mismatch
    assert 0.5 + 100.0 / 1200.0 < cycles * 0.01 < 0.5 + 100.0 / 1200.0 + 0.03
    assert "measured 2400.0 V, commanded 0.0 V" in channel.fault_text
    assert "following at the device ramp of 1200 V/s" in channel.fault_text


def test_an_output_left_on_by_an_earlier_session_may_ramp_down_after_open():
    channel = ChannelSupervisor(GRIPPER, nominal_period_s=PERIOD)
    channel.set_device_ramp(1200.0)
    channel.output_found(0.0, 2400.0)
    rig = Rig(channel, 1200.0, voltage=2400.0)
    for _ in range(300):
        rig.cycle(0.01)
    assert not channel.faults and rig.voltage == 0.0
    stuck = ChannelSupervisor(GRIPPER, nominal_period_s=PERIOD)
    stuck.set_device_ramp(1200.0)
    stuck.output_found(0.0, 2400.0)
    rig = Rig(stuck, 1200.0, voltage=2400.0)
    for _ in range(100):
        rig.cycle(0.01, measured=2400.0)
    assert stuck.faults == Fault.READBACK_MISMATCH


@pytest.mark.parametrize("rate", [0.0, -1.0, math.nan, math.inf])
def test_an_absurd_device_ramp_is_refused(rate):
    with pytest.raises(ValueError, match="device_ramp"):
        ChannelSupervisor(GAIT).set_device_ramp(rate)


# --- property-based ---------------------------------------------------------------------------
intervals = st.lists(st.one_of(st.just(0.01), st.floats(min_value=0.002, max_value=0.03),
                               st.floats(min_value=0.03, max_value=2.0)), min_size=20, max_size=200)
events = st.dictionaries(st.integers(min_value=0, max_value=199),
                         st.one_of(st.floats(min_value=0.0, max_value=3000.0), st.sampled_from(["off", "reset"])),
                         max_size=12)


@settings(max_examples=200, deadline=None)
@given(slew=st.floats(min_value=500.0, max_value=16000.0), device_error=st.floats(min_value=0.98, max_value=1.02),
       delay=st.floats(min_value=0.0, max_value=0.002), noise=st.floats(min_value=-20.0, max_value=20.0),
       intervals=intervals, events=events)
def test_a_device_that_follows_at_its_ramp_never_trips_the_readback_check(slew, device_error, delay, noise,
                                                                          intervals, events):
    """Any loop timing (stalls up to 2 s), ramps, disables and resets: a readback that follows the commands
    at the device ramp (within 2 % and 20 V of noise) is never a mismatch."""
    config = ChannelConfig("ch", 0, max_voltage_v=3000.0, slew_rate_v_per_s=slew)
    channel = ChannelSupervisor(config, nominal_period_s=PERIOD)
    channel.set_device_ramp(DEVICE_MARGIN * slew)
    channel.enable()
    rig = Rig(channel, DEVICE_MARGIN * slew * device_error, delay)
    for k, interval in enumerate(intervals):
        event = events.get(k)
        if event == "off":
            channel.disable(rig.t)
        elif event == "reset":
            channel.reset()
            channel.enable()
        elif event is not None and channel.output_enabled:
            channel.ramp_to(rig.t, event)
        rig.cycle(interval, noise=noise)
        assert not channel.faults, channel.fault_text


@settings(max_examples=200, deadline=None)
@given(start=st.floats(min_value=300.0, max_value=3000.0), slew=st.floats(min_value=500.0, max_value=16000.0),
       intervals=st.lists(st.floats(min_value=0.001, max_value=1.0), min_size=1, max_size=10))
def test_an_output_that_does_not_fall_always_trips(start, slew, intervals):
    """Switched off at ``start`` V and stuck there: trips after the tolerance is ramped through and the
    mismatch has been seen for mismatch_time of loop time (each interval counted up to one nominal period)."""
    config = ChannelConfig("ch", 0, max_voltage_v=3000.0, slew_rate_v_per_s=slew)
    channel = ChannelSupervisor(config, nominal_period_s=PERIOD)
    rate = DEVICE_MARGIN * slew
    channel.set_device_ramp(rate)
    channel.output_found(0.0, start)
    t, credited = 0.0, None
    for k in range(5000):
        interval = intervals[k % len(intervals)]
        t += interval
        channel.step(t)
        channel.observe(t, start, 1e-7)
        if channel.faults:
            break
        if start - max(0.0, start - rate * t) > config.mismatch_tolerance_v:  # off the expectation
            credited = 0.0 if credited is None else credited + min(interval, 0.01)
    assert channel.faults == Fault.READBACK_MISMATCH
    assert credited is not None and credited <= config.mismatch_time_s + 1e-9
