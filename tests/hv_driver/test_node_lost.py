"""NODE_LOST in the pure supervisor (time passed in): the node's loss ends its client's session, latches on every
channel, ramps every energised output to 0 V within the slew limit and never re-energises anything by itself."""
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from hv_driver import ChannelConfig, ControlError, Fault, FaultLatchedError, Supervisor

SLEW = 1000.0
CONFIGS = [ChannelConfig(name, k, slew_rate_v_per_s=SLEW) for k, name in enumerate(("front", "back", "legs"))]


def stepped(supervisor: Supervisor, start: float, end: float, period: float = 0.01):
    t, commands = start, None
    while t <= end:
        commands = supervisor.step(t)
        for name, command in commands.items():  # a device that follows its setpoint exactly
            supervisor.channel(name).observe(t, command.setpoint if command.output_on else 0.0, 0.0)
        t += period
    return commands


@settings(deadline=None, max_examples=60)
@given(targets=st.lists(st.one_of(st.just(0.0), st.floats(min_value=1.0, max_value=2400.0)), min_size=3, max_size=3),
       lost_after=st.floats(min_value=0.0, max_value=3.0))
def test_a_lost_node_ramps_every_energised_output_down_and_nothing_comes_back(targets, lost_after):
    supervisor = Supervisor(CONFIGS, link_timeout_s=0.5, heartbeat_timeout_s=math.inf)
    token = supervisor.claim_control("sequencer", 0.0)
    for config, target in zip(CONFIGS, targets):
        supervisor.enable(config.name, 0.0)
        supervisor.ramp_to(config.name, 0.0, target, token=token)
    stepped(supervisor, 0.0, lost_after)
    highest = max(c.setpoint for c in supervisor.channels.values())
    supervisor.node_lost(lost_after, "HV driver node lost: test")
    just_after = supervisor.step(lost_after + 0.01)
    assert all(c.faults == Fault.NODE_LOST for c in supervisor.channels.values())
    assert all(not c.emergency_off for c in just_after.values())  # ramped, not cut: no jump on the DEA film
    # a minimum-jerk ramp at the slew limit takes 15/8 x (voltage / slew) to reach 0 V
    commands = stepped(supervisor, lost_after + 0.02, lost_after + 1.875 * highest / SLEW + 0.1)
    assert all(c.setpoint == 0.0 and not c.output_on for c in commands.values())
    assert supervisor.control.owner is None
    try:
        supervisor.ramp_to("front", lost_after + 5.0, 100.0, token=token)
        raise AssertionError("the lost node's session still commands")
    except ControlError:
        pass
    new = supervisor.claim_control("operator", lost_after + 5.0)
    for name in supervisor.channels:
        try:
            supervisor.enable(name, lost_after + 5.0)
            raise AssertionError("enabled with NODE_LOST latched")
        except FaultLatchedError:
            pass
    assert sorted(supervisor.reset(lost_after + 5.0)) == sorted(supervisor.channels)
    commands = stepped(supervisor, lost_after + 5.0, lost_after + 6.0)
    assert all(c.setpoint == 0.0 and not c.output_on for c in commands.values())  # a reset energises nothing
    supervisor.enable("front", lost_after + 6.0)
    supervisor.ramp_to("front", lost_after + 6.0, 100.0, token=new)  # only now, by the new session
