"""Execution of one hv/pulse (PulseChannels) goal against the driver: the train runs on the device or in the
driver's loop; this only starts it, reports cycles and voltages, and cancels it (channels back to 0 V)."""
from __future__ import annotations

from softblock_interfaces.action import PulseChannels

from hv_driver import HvError, HvSupply
from hv_driver.control import signed

from .hv_ramp_goal import abort_goal, end_goal

FEEDBACK_PERIOD = 0.1  # [s]
EDGES = {PulseChannels.Goal.EDGE_SMOOTH: "smooth", PulseChannels.Goal.EDGE_SQUARE: "square"}


def execute_pulse_goal(supply: HvSupply, goal_handle) -> PulseChannels.Result:
    """Run the goal to its end; a refused request (a waveform the supply cannot produce, a limit, a fault, an
    unknown channel, not the client holding control) aborts with the reason before anything is energised."""
    goal, result = goal_handle.request, PulseChannels.Result()
    try:
        edge = EDGES.get(goal.edge)
        if edge is None:
            raise ValueError(f"edge={goal.edge}: EDGE_SMOOTH ({PulseChannels.Goal.EDGE_SMOOTH}) or EDGE_SQUARE "
                             f"({PulseChannels.Goal.EDGE_SQUARE})")
        handle = supply.pulse(list(goal.channels), goal.amplitude, goal.frequency, goal.duty, goal.phase,
                              goal.cycles, edge, goal.slew_rate or None,
                              token=signed(goal.session, goal.counter, goal.mac))
    except (HvError, ValueError) as error:
        result.message = str(error)
        goal_handle.abort()
        return result
    canceled = False
    try:
        while not handle.wait(FEEDBACK_PERIOD):
            if goal_handle.is_cancel_requested and not canceled:
                handle.cancel()
                canceled = True
            snapshot = supply.snapshot()
            goal_handle.publish_feedback(PulseChannels.Feedback(
                cycles_done=handle.cycles_done,
                measured_voltage=[snapshot.channel(name).measured_voltage for name in goal.channels]))
        result.cycles_done, result.frequency, result.generated_by = handle.cycles_done, handle.frequency, \
            handle.generated_by
        return end_goal(goal_handle, result, handle, canceled,
                        f"canceled after {handle.cycles_done} cycles: {handle.message}")
    except HvError as error:  # the supervisor process lost or closed while the train ran
        return abort_goal(goal_handle, result, error)
