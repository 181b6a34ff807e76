"""Parameters of the hv_driver node (defaults from hv_driver's ChannelConfig and HvSupply) and what they give."""
from __future__ import annotations

import math

from hv_driver import DIALECTS, ChannelConfig, HvSupply, IsegEdcp
from hv_driver.realtime import DEFAULT_PRIORITY
from hv_driver.ipc import NODE_KEEPALIVE_TIMEOUT_S
from hv_driver.server import ORPHAN_TIMEOUT_S

from .parameters import Param, ParameterError

PARAMETERS = (
    Param("backend", "sim", "'sim' (simulated supplies) or 'serial' (the ports parameter); never swapped",
          kind=str, choices=("sim", "serial")),
    Param("sim_link", "memory", "backend 'sim': 'memory' (the supplies answer within the driver's exchange, "
          "whatever the host's load) or 'pty' (a real-time process of their own on pseudo-terminals: the serial "
          "path of real hardware, answering late when the host deschedules it)", kind=str, choices=("memory", "pty")),
    Param("dialect", IsegEdcp.name, "the supply's command set and capabilities", kind=str, choices=tuple(DIALECTS)),
    Param("ports", [], "serial devices or pyserial URLs, one per supply (backend 'serial'; 'sim' makes its own)",
          kind=str, size=(0, 16)),
    Param("baudrate", 0, "serial baud rate; 0 = the dialect's default (iseg 9600, Keithley 9600, PPV 115200)",
          low=0, high=921600, kind=int),
    Param.of(HvSupply, "expected_identity", "text the supply's *IDN? answer must contain, checked at configure; "
             "empty = not checked (logged)"),
    Param("channel_names", ["front", "back"], "channel names", kind=str, size=(1, 16)),
    Param("channel_indices", [0, 1], "channel numbers on their supply, one per name (0 on a single-channel supply)",
          low=0, high=63, kind=int, size=(1, 16)),
    Param("channel_devices", [], "which supply each channel is on: its position in ports (one per name); "
          "empty = every channel on the first", low=0, high=15, kind=int, size=(0, 16)),
    Param.of(ChannelConfig, "max_voltage_v", "hard maximum of every channel", "V", 1.0, 10000.0),
    Param.of(ChannelConfig, "slew_rate_v_per_s", "maximum slew rate", "V/s", 1.0, 100000.0),
    Param.of(ChannelConfig, "current_trip_a", "over-current trip level", "A", 1e-9, 0.1),
    Param.of(ChannelConfig, "mismatch_tolerance_v", "readback further than this from the command, allowing for "
             "the device's own ramp ...", "V", 1.0, 1000.0),
    Param.of(ChannelConfig, "mismatch_time_s", "... for longer than this trips READBACK_MISMATCH", "s", 0.01, 10.0),
    Param.of(ChannelConfig, "creep_voltage_v", "creep guard: continuous time at or above this voltage ...; "
             "0 = no creep guard", "V", 0.0, 10000.0, none_as=0.0),
    Param.of(ChannelConfig, "max_time_at_voltage_s", "... longer than this trips TIME_AT_VOLTAGE; 0 = no creep guard",
             "s", 0.0, 1e6, none_as=0.0),
    Param.of(HvSupply, "loop_rate_hz", "control loop rate (lower it for a 9600-baud link)", "Hz", 1.0, 1000.0),
    Param.of(HvSupply, "link_timeout_s", "no valid reply for this long trips LINK", "s", 0.1, 10.0),
    Param.of(HvSupply, "heartbeat_timeout_s", "the client holding control (hv/claim_control) must send hv/heartbeat "
             "this often or its control lapses and its energised outputs ramp to 0 V; .inf = off (logged)", "s",
             0.05, math.inf),
    Param("publish_rate_hz", 50.0, "hv/state rate", "Hz", 20.0, 200.0),
    Param("realtime_priority", DEFAULT_PRIORITY, "SCHED_FIFO priority of the supervisor process where the host "
          "permits it (else normal priority, logged); 0 = normal priority on purpose (logged)", low=0, high=99,
          kind=int),
    Param("node_keepalive_timeout_s", NODE_KEEPALIVE_TIMEOUT_S, "the supervisor process latches NODE_LOST and ramps "
          "every energised output to 0 V when this node's keep-alive stops for this long (its death: at once)", "s",
          0.2, 10.0),
    Param("orphan_timeout_s", ORPHAN_TIMEOUT_S, "a supervisor process without its node this long switches every "
          "output off, closes the ports and exits; a node restarted within it takes it over, faults latched", "s",
          1.0, 3600.0),
    Param("supervisor_socket", "", "Unix socket of the supervisor process; empty = a path fixed by the node's "
          "name, ROS domain and ports in a directory of the user's own: either way a restarted node takes its "
          "supervisor over", kind=str),
    Param("autostart", True, "configure and activate at start (console script / python -m)", kind=bool),
)


def channel_configs(values: dict) -> list[ChannelConfig]:
    """One ChannelConfig per configured channel; ParameterError naming the parameters when they do not fit."""
    names, indices = values["channel_names"], values["channel_indices"]
    devices = values["channel_devices"] or [0] * len(names)
    if len(names) != len(indices) or len(devices) != len(names) or len(set(names)) != len(names) \
            or len(set(zip(devices, indices))) != len(indices):
        raise ParameterError(f"parameters channel_names={names}, channel_indices={indices} and channel_devices="
                             f"{values['channel_devices']} refused: give one index (and device) per distinct name, "
                             "no two channels at the same index of the same supply")
    if (values["creep_voltage_v"] == 0.0) != (values["max_time_at_voltage_s"] == 0.0):
        raise ParameterError(f"parameters creep_voltage_v={values['creep_voltage_v']} and max_time_at_voltage_s="
                             f"{values['max_time_at_voltage_s']} refused: set both (creep guard) or neither")
    limits = {name: values[name] for name in ("max_voltage_v", "slew_rate_v_per_s", "current_trip_a",
                                              "mismatch_tolerance_v", "mismatch_time_s")}
    limits.update({name: values[name] or None for name in ("creep_voltage_v", "max_time_at_voltage_s")})  # 0 = off
    return [ChannelConfig(name, index, device=device, **limits) for name, index, device in zip(names, indices, devices)]


def device_count(channels: list[ChannelConfig]) -> int:
    """Supplies the channels are spread over (ports needed)."""
    return max(c.device for c in channels) + 1
