"""Parameters of the hv_driver node: declaration with descriptors and ranges, and the channel limits they give."""
from __future__ import annotations

import math

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from hv_driver import ChannelConfig

PARAMETERS = {  # name: (default, description, range)
    "backend": ("sim", "'sim' (simulated supply on a pty) or 'serial' (the port parameter); never swapped", None),
    "port": ("", "serial device or pyserial URL of the supply (backend 'serial')", None),
    "baudrate": (9600, "serial baud rate", IntegerRange(from_value=1200, to_value=921600)),
    "channel_names": (["front", "back"], "channel names", None),
    "channel_indices": ([0, 1], "channel numbers on the supply, one per name", None),
    "max_voltage": (3000.0, "hard maximum of every channel [V]", FloatingPointRange(from_value=1.0, to_value=10000.0)),
    "slew_rate": (1000.0, "maximum slew rate [V/s]", FloatingPointRange(from_value=1.0, to_value=100000.0)),
    "current_trip": (50e-6, "over-current trip level [A]", FloatingPointRange(from_value=1e-9, to_value=0.1)),
    "link_timeout": (0.5, "no valid reply for this long trips LINK [s]", FloatingPointRange(from_value=0.1, to_value=10.0)),
    "heartbeat_timeout": (2.0, "the client holding control must send hv/heartbeat this often or its energised "
                               "outputs ramp to 0 V [s]; .inf switches the watchdog off (warned at every start)",
                          FloatingPointRange(from_value=0.05, to_value=math.inf)),
    "state_rate": (50.0, "hv/state rate [Hz]", FloatingPointRange(from_value=20.0, to_value=200.0)),
    "autostart": (True, "configure and activate at start (console script / python -m)", None),
}


def declare_parameters(node: Node) -> None:
    for name, (default, description, value_range) in PARAMETERS.items():
        descriptor = ParameterDescriptor(description=description, read_only=True)
        if isinstance(value_range, FloatingPointRange):
            descriptor.floating_point_range = [value_range]
        elif isinstance(value_range, IntegerRange):
            descriptor.integer_range = [value_range]
        node.declare_parameter(name, default, descriptor)


def channel_configs(node: Node) -> list[ChannelConfig]:
    """One ChannelConfig per configured channel; ValueError naming the parameter when they do not fit."""
    names, indices = node.get_parameter("channel_names").value, node.get_parameter("channel_indices").value
    if len(names) != len(indices):
        raise ValueError(f"channel_names {names} and channel_indices {indices} differ in length")
    limits = [node.get_parameter(p).value for p in ("max_voltage", "slew_rate", "current_trip")]
    return [ChannelConfig(name, int(index), *limits) for name, index in zip(names, indices)]
