"""Execution of one hv/ramp (RampChannel) goal against the driver: feedback while ramping, cancel ramps to 0 V."""
from __future__ import annotations

from softblock_interfaces.action import RampChannel

from hv_driver import HvError, HvSupply
from hv_driver.control import signed

FEEDBACK_PERIOD = 0.05  # [s]


def execute_ramp_goal(supply: HvSupply, goal_handle) -> RampChannel.Result:
    """Run the goal to its end; a refused request (limit, fault, unknown channel, not the client holding
    control) aborts with the reason."""
    goal, result = goal_handle.request, RampChannel.Result()
    try:
        handle = supply.ramp_to(goal.channel, goal.target, goal.slew_rate or None,
                                 token=signed(goal.session, goal.counter, goal.mac))
    except HvError as error:  # a limit, a latched fault, the output off, an unknown channel, not in control
        result.message = str(error)
        goal_handle.abort()
        return result
    try:
        start, canceled = supply.snapshot().channel(goal.channel).setpoint, False
        while not handle.wait(FEEDBACK_PERIOD):
            if goal_handle.is_cancel_requested and not canceled:  # ramp back to 0 V, then report
                handle, canceled = handle.cancel() or handle, True
            channel = supply.snapshot().channel(goal.channel)
            span = goal.target - start
            goal_handle.publish_feedback(RampChannel.Feedback(
                setpoint=channel.setpoint, measured_voltage=channel.measured_voltage,
                progress=1.0 if span == 0 else min(1.0, max(0.0, (channel.setpoint - start) / span))))
        result.final_voltage = supply.snapshot().channel(goal.channel).measured_voltage
        return end_goal(goal_handle, result, handle, canceled, f"canceled: {handle.message}")
    except HvError as error:  # the supervisor process lost or closed while the ramp ran
        return abort_goal(goal_handle, result, error)


def abort_goal(goal_handle, result, error: HvError):
    result.success, result.message = False, str(error)
    goal_handle.abort()
    return result


def end_goal(goal_handle, result, handle, canceled: bool, canceled_message: str):
    """Set the goal's final status from how the driver's ``handle`` ended (success, message)."""
    result.success, result.message = handle.succeeded and not canceled, handle.message
    if canceled:
        result.message = canceled_message
        goal_handle.canceled()
    elif result.success:
        goal_handle.succeed()
    else:
        goal_handle.abort()
    return result
