"""Latched fault flags of one HV channel.

The bit values equal the FAULT_* constants of softblock_interfaces/msg/HvChannelState.msg, so a
`Fault` converts to the message field with `int(fault)`.
"""
from enum import IntFlag


class Fault(IntFlag):
    """Latched fault bits; cleared only by an explicit reset."""

    OVER_CURRENT = 1        # measured current above the trip level (film breakdown / arc)
    READBACK_MISMATCH = 2   # measured voltage off the commanded one for too long
    LINK = 4                # no, garbled or wrong reply from the supply
    HEARTBEAT = 8           # controlling client went silent
    TIME_AT_VOLTAGE = 16    # continuous time above the creep threshold exceeded
    ESTOP = 32              # emergency stop
    DEVICE = 64             # the supply itself reported a trip, interlock or reset
    BREAKDOWN = 128         # the output voltage collapsed far below a held setpoint (supply without current readback)
    NODE_LOST = 256         # the ROS node driving the supervisor process closed its channel or stopped its keep-alive
    CUT_UNCONFIRMED = 512   # after a cut the device still reports its output on (or its voltage does not fall)
    SUPERVISOR_LOST = 1024  # the supervisor process died: only the device's own means still hold (set by the node)


def fault_names(faults: Fault) -> str:
    """Names of the set bits in ascending bit order, e.g. ``"over_current, link"``."""
    return ", ".join(f.name.lower() for f in Fault if f in faults)
