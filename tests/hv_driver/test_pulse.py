"""Pulse-train planning (pure): what each supply can produce, refusals naming the limit, the waveform, the shared
time grid, and the supervisor's checks while the device switches."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hv_driver import ChannelConfig, Fault, PulseLimitError, SettingError, StateError
from hv_driver.dialects import IsegEdcp, Keithley2290, PetaPicoVoltron
from hv_driver.pulse import LEAD_S, MAX_TRAIN_S, MIN_FREQUENCY_HZ, plan_pulse_train
from hv_driver.ramp import MIN_JERK_PEAK_RATE
from hv_driver.supervisor import ChannelSupervisor

pytestmark = pytest.mark.fast

CONFIG = ChannelConfig("leg", 0, max_voltage_v=3000.0, slew_rate_v_per_s=16000.0)
PERIOD = 0.01


def plan(dialect, amplitude=600.0, frequency=5.0, duty=0.5, phase=0.0, cycles=10, edge="smooth", slew=None,
         now=100.0, config=CONFIG):
    return plan_pulse_train(config, dialect.capabilities, dialect.name, now, PERIOD, amplitude, frequency, duty,
                            phase, cycles, edge, slew)


def test_five_hertz_at_2400_v_on_an_iseg_is_refused_naming_the_slew_and_device_ramp():
    with pytest.raises(PulseLimitError) as refused:
        plan(IsegEdcp, amplitude=2400.0)
    assert str(refused.value) == ("channel 'leg': 5 Hz at 2400 V with duty 0.5 needs edges of at most 100 ms; a "
                                  "smooth edge over 2400 V takes 281 ms at the slew limit of 16000 V/s (the device "
                                  "ramp is set to 19200 V/s)")


@pytest.mark.parametrize("fields, message", [
    (dict(edge="square", frequency=6000.0), r"frequency 6000 Hz outside the ppv supply's switching range 0.001-5000"),
    (dict(edge="square", duty=0.3), r"duty 0.3, but the ppv supply switches with a fixed duty of 0.5"),
    (dict(edge="square", cycles=70000, frequency=100.0), r"70000 cycles, the ppv supply counts at most 65535"),
    (dict(slew=1000.0), r"smooth edge over 600 V takes 1125 ms"),
    (dict(frequency=0.5, amplitude=10.0), r"shorter than 2 periods of the 100 Hz control loop"),
    (dict(duty=1.0), r"duty=1.0: between 0 and 1"),
    (dict(phase=1.0), r"phase=1.0: in \[0, 1\)"),
    (dict(cycles=0), r"cycles=0: an integer >= 1"),
    (dict(cycles=True), r"cycles=True: an integer >= 1"),
    (dict(frequency=math.inf), r"frequency=inf: finite number >= MIN_FREQUENCY_HZ \(0.01 Hz\)"),
    (dict(frequency=1e-9, edge="square"), r"frequency=1e-09: finite number >= MIN_FREQUENCY_HZ \(0.01 Hz\)"),
    (dict(frequency=1e-9), r"frequency=1e-09: finite number >= MIN_FREQUENCY_HZ"),
    (dict(frequency=20.0, cycles=72001, edge="square"),
     r"cycles=72001: at most MAX_TRAIN_S \(3600 s\) of train: 72001 cycles at 20 Hz \(phase 0\) last 3600.05 s"),
    (dict(frequency=0.01, cycles=36, phase=0.5, amplitude=10.0, slew=1000.0),
     r"cycles=36: at most MAX_TRAIN_S \(3600 s\) of train: 36 cycles at 0.01 Hz \(phase 0.5\) last 3650 s"),
    (dict(amplitude=math.nan), r"amplitude=nan: finite number > 0"),
    (dict(edge="triangle"), r"edge='triangle': one of smooth, square"),
    (dict(slew=20000.0), r"slew_rate=20000 V/s exceeds the configured slew limit 16000 V/s"),
])
def test_requests_the_supply_cannot_produce_are_refused_naming_the_limit(fields, message):
    with pytest.raises(SettingError, match=message):
        plan(PetaPicoVoltron, **fields)


@given(frequency=st.floats(0.01, 5000.0), cycles=st.integers(1, 65535), phase=st.floats(0.0, 0.999))
def test_every_planned_train_starts_within_a_period_and_ends_within_max_train_s(frequency, cycles, phase):
    try:
        train = plan(PetaPicoVoltron, frequency=frequency, cycles=cycles, phase=phase, edge="square")
    except PulseLimitError:
        return
    except SettingError as refused:
        assert "MAX_TRAIN_S" in str(refused) and (cycles + phase) / frequency > MAX_TRAIN_S
        return
    assert train.start - 100.0 <= LEAD_S + 2.0 / MIN_FREQUENCY_HZ and train.stop - train.start <= MAX_TRAIN_S


@pytest.mark.parametrize("dialect", [IsegEdcp, Keithley2290])
def test_square_edges_need_a_supply_that_switches_itself(dialect):
    with pytest.raises(PulseLimitError, match=f"the {dialect.name} supply does not"):
        plan(dialect, edge="square")


def test_the_smooth_waveform_has_minimum_jerk_edges_within_each_period():
    train = plan(Keithley2290, slew=16000.0)
    rise = MIN_JERK_PEAK_RATE * 600.0 / 16000.0
    start = train.start
    assert train.value(start - 1e-6) == 0.0 and train.value(start) == 0.0
    assert train.value(start + rise / 2) == pytest.approx(300.0)
    assert train.value(start + 0.08) == 600.0  # on-phase after the 70 ms edge
    assert train.value(start + 0.1 + rise / 2) == pytest.approx(300.0)  # falling edge at duty x period
    assert train.value(start + 0.19) == 0.0
    assert train.value(train.stop) == 0.0 and train.finished(train.stop)
    assert train.cycles_done(start + 0.45) == 2


@settings(deadline=None)  # hypothesis's per-example deadline is wall-clock time
@given(now=st.floats(min_value=0.0, max_value=1e5), delay=st.floats(min_value=0.0, max_value=0.5))
def test_trains_of_one_frequency_share_a_time_grid(now, delay):
    """Two trains sent at different times (e.g. the two diagonal leg pairs of a gait) keep their phase relation."""
    a = plan(PetaPicoVoltron, edge="square", now=now)
    b = plan(PetaPicoVoltron, edge="square", phase=0.5, now=now + delay)
    assert a.start >= now + LEAD_S and b.start >= now + delay + LEAD_S
    shift = (b.start - a.start) * 5.0
    assert shift - math.floor(shift) == pytest.approx(0.5, abs=1e-6)


@pytest.fixture
def switching():
    """A PPV channel (breakdown guard on) running a square 5 Hz train planned at t = 0: (channel, train)."""
    channel = ChannelSupervisor(CONFIG, nominal_period_s=PERIOD)
    channel.breakdown_guard = True
    channel.enable()
    train = plan(PetaPicoVoltron, edge="square", now=0.0)
    channel.pulse(0.0, train)
    return channel, train


def test_a_square_train_holds_the_amplitude_while_the_device_switches_and_drops_at_once_when_stopped(switching):
    channel, train = switching
    armed = channel.step(0.01)
    assert armed.pulse is train and armed.setpoint == 0.0
    running = channel.step(train.start + 0.01)
    assert running.pulse is train and running.setpoint == 600.0
    for k in range(20):  # the device's own square wave: 0 V half the time is consistent, no fault
        t = train.start + 0.01 * (k + 2)
        channel.step(t)
        channel.observe(t, 600.0 if (t - train.start) % 0.2 < 0.1 else 0.0, None)
    assert not channel.faults
    channel.ramp_to(train.start + 0.3, 0.0)
    stopped = channel.step(train.start + 0.31)
    assert stopped.pulse is None and stopped.setpoint == 0.0


def test_no_pulse_reaching_half_the_amplitude_for_two_periods_is_a_breakdown(switching):
    channel, train = switching
    t = train.start
    while not channel.faults and t < train.start + 1.0:
        t += 0.01
        channel.step(t)
        channel.observe(t, 100.0, None)  # the film shorted: the output never rises
    assert Fault.BREAKDOWN in channel.faults and "no pulse of the 5 Hz train" in channel.fault_text
    assert t - train.start == pytest.approx(2 * train.period, abs=0.03)


def test_a_square_train_starts_from_0_v():
    channel = ChannelSupervisor(CONFIG)
    channel.enable()
    channel.ramp_to(0.0, 300.0)
    for k in range(1, 101):
        channel.step(0.01 * k)
    with pytest.raises(StateError, match="at 300 V; square edges start from 0 V"):
        channel.pulse(1.0, plan(PetaPicoVoltron, edge="square", now=1.0))


@pytest.mark.parametrize("interval, short", [(0.01, 0), (0.08, 10)])
def test_a_loop_too_slow_for_a_streamed_train_counts_its_short_pulses(interval, short):
    """The slew allowance per cycle is capped at two nominal periods: a loop running at 12.5 Hz instead of 100 Hz
    cannot reach 600 V within a 100 ms on-phase, and says so instead of reporting a completed train."""
    channel = ChannelSupervisor(CONFIG, 0.0, PERIOD)
    channel.enable()
    train = plan(Keithley2290, now=0.0)  # 5 Hz, 600 V, 10 cycles, 70 ms edges at 16 kV/s
    channel.pulse(0.0, train)
    t = 0.0
    while channel.pulse_train is not None and t < train.stop + 1.0:
        t += interval
        channel.step(t)
    assert channel.pulse_tally.short == short
    assert channel.pulse_tally.longest_gap == pytest.approx(interval)


def test_a_loop_that_stands_still_through_an_on_phase_counts_that_pulse_short_and_names_its_gap():
    """A stall of one on-phase costs that pulse alone, and the tally names the stall (a fresh-clone run's pulse
    test reported short pulses without saying how long its loop had stood still)."""
    channel = ChannelSupervisor(CONFIG, 0.0, PERIOD)
    channel.enable()
    train = plan(Keithley2290, now=0.0)  # 5 Hz: on for 100 ms of each 200 ms period
    channel.pulse(0.0, train)
    t, stalled = 0.0, False
    while channel.pulse_train is not None and t < train.stop + 1.0:
        stall = not stalled and t >= train.start + 0.405  # from just into period 3's on-phase to its off-phase
        stalled |= stall
        t += 0.13 if stall else PERIOD
        channel.step(t)
    assert channel.pulse_tally.short == 1
    assert channel.pulse_tally.longest_gap == pytest.approx(0.13)


def test_a_stopped_streamed_train_counts_only_the_periods_it_ran():
    channel = ChannelSupervisor(CONFIG, 0.0, PERIOD)
    channel.enable()
    train = plan(Keithley2290, now=0.0)
    channel.pulse(0.0, train)
    t = 0.0
    while t < train.start + 0.35:  # one and three quarter periods, then a ramp to 0 V ends it
        t += PERIOD
        channel.step(t)
    channel.ramp_to(t, 0.0)
    assert channel.pulse_tally.short == 0
