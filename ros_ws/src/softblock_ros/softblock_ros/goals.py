"""Ending an action goal: one place that maps how the work ended to the goal's final status."""
from __future__ import annotations


def settle(goal_handle, canceled: bool, success: bool) -> None:
    """Mark the goal canceled, succeeded or aborted (in that order of precedence)."""
    if canceled:
        goal_handle.canceled()
    elif success:
        goal_handle.succeed()
    else:
        goal_handle.abort()
