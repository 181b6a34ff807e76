"""Every error the driver raises on purpose is an HvError; the device identity is checked at open."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hv_driver import (ChannelConfig, ConfigurationError, ControlError, FaultLatchedError, HvError, HvSupply, LimitError,
                       LinkError, SettingError, StateError, Supervisor)
from sim_fallback.hv_supply import IDENTITY
from sim_fallback.memory_port import MemoryPort


def test_the_driver_errors_share_one_base_and_keep_their_builtin_kinds():
    for error, builtin in ((SettingError, ValueError), (LimitError, ValueError), (StateError, RuntimeError),
                           (FaultLatchedError, RuntimeError), (ConfigurationError, RuntimeError),
                           (ControlError, RuntimeError), (LinkError, ConnectionError)):
        assert issubclass(error, HvError) and issubclass(error, builtin)


@settings(deadline=None)  # hypothesis's per-example deadline is wall-clock time
@given(st.sampled_from(["max_voltage_v", "slew_rate_v_per_s", "current_trip_a", "mismatch_tolerance_v",
                        "mismatch_time_s"]),
       st.one_of(st.floats(max_value=0.0), st.just(math.nan), st.just(math.inf)))
def test_a_bad_channel_setting_is_an_hv_error_naming_it(field, value):
    with pytest.raises(HvError, match=field):
        ChannelConfig("front", 0, **{field: value})


def test_refused_requests_are_hv_errors(channels):
    supervisor = Supervisor(channels, link_timeout_s=1.0)
    token = supervisor.claim_control("operator", 0.0)
    with pytest.raises(StateError, match="output not enabled"):
        supervisor.ramp_to("front", 0.0, 100.0, token=token)
    supervisor.enable("front", 0.0)
    with pytest.raises(LimitError):
        supervisor.ramp_to("front", 0.0, 1e6, token=token)
    with pytest.raises(ControlError, match="held by 'operator'"):
        supervisor.ramp_to("front", 0.0, 100.0, token="not-the-session")
    with pytest.raises(SettingError, match="channel='left'"):
        supervisor.channel("left")
    with pytest.raises(SettingError, match="loop_rate_hz"):
        HvSupply("loop://", channels=channels, loop_rate_hz=0.0)


def test_a_port_that_cannot_be_opened_is_a_link_error(channels):
    with pytest.raises(LinkError, match="cannot open '/dev/no-such-supply'"):
        HvSupply("/dev/no-such-supply", channels=channels, handle_signals=False).open()


def test_open_refuses_a_device_whose_identity_lacks_the_expected_text(sim, clock, channels):
    supply = HvSupply(MemoryPort(sim), channels=channels, handle_signals=False, expected_identity="SHR 4060",
                      clock=clock)
    with pytest.raises(ConfigurationError, match=r"identifies as .*NHR 42 50r.*expected_identity='SHR 4060'"):
        supply.open()
    assert not any(channel.output_on for channel in sim.plant)


def test_open_accepts_the_expected_identity_and_an_empty_one_checks_nothing(sim, clock, channels):
    for expected in ("NHR 42 50r", ""):
        supply = HvSupply(MemoryPort(sim), channels=channels, handle_signals=False, expected_identity=expected,
                          clock=clock).open()
        try:
            assert supply.device_id == IDENTITY
        finally:
            supply.close()
