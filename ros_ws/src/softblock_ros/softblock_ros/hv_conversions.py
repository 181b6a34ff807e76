"""HV driver snapshots to ROS messages: softblock_interfaces/HvState and diagnostic_msgs/DiagnosticArray."""
from __future__ import annotations

import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from softblock_interfaces.msg import HvChannelState, HvState
from std_msgs.msg import Header

from hv_driver import SupplySnapshot


def hv_state_msg(snapshot: SupplySnapshot, backend: str, stamp: Time) -> HvState:
    return HvState(
        header=Header(stamp=stamp),
        device_id=snapshot.device_id,
        backend=backend,
        estop=snapshot.estop,
        channels=[HvChannelState(name=c.name, index=c.index, setpoint=c.setpoint, target=c.target,
                                 measured_voltage=c.measured_voltage, measured_current=c.measured_current,
                                 ceiling=c.ceiling, output_enabled=c.output_enabled, ramping=c.ramping,
                                 faults=int(c.faults), fault_text=c.fault_text)
                  for c in snapshot.channels])


CONTROL_STATUS = ": control"  # suffix of the control status's name, after the node name


def control_status(snapshot: SupplySnapshot, node_name: str) -> DiagnosticStatus:
    """Who holds control and how fresh its heartbeat is; WARN when the heartbeat watchdog is off."""
    timeout = snapshot.heartbeat_timeout_s
    if snapshot.controller:
        message = f"held by {snapshot.controller!r}, last heartbeat {snapshot.heartbeat_age_s:.2f} s ago"
    else:
        message = "no client holds control"
    level = DiagnosticStatus.OK
    if math.isinf(timeout):
        level, message = DiagnosticStatus.WARN, message + "; heartbeat watchdog OFF"
    values = {"controller": snapshot.controller,
              "heartbeat_age_s": "" if snapshot.heartbeat_age_s is None else f"{snapshot.heartbeat_age_s:.3f}",
              "heartbeat_timeout_s": timeout}
    return DiagnosticStatus(level=level, name=f"{node_name}{CONTROL_STATUS}", message=message,
                            hardware_id=snapshot.device_id,
                            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])


def control_values(array: DiagnosticArray) -> dict | None:
    """The control status's values (controller, heartbeat_age_s, heartbeat_timeout_s: text, as published) from
    a /diagnostics message; None when it carries no control status."""
    status = next((s for s in array.status if s.name.endswith(CONTROL_STATUS)), None)
    return None if status is None else {kv.key: kv.value for kv in status.values}


def diagnostics_msg(snapshot: SupplySnapshot, node_name: str, backend: str, stamp: Time) -> DiagnosticArray:
    """The control status, then one status per channel: ERROR with latched faults, WARN while the link has
    errors, else OK."""
    statuses = [control_status(snapshot, node_name)]
    for c in snapshot.channels:
        if c.faults:
            level, message = DiagnosticStatus.ERROR, f"faults latched: {c.fault_text}"
        elif snapshot.link_error:
            level, message = DiagnosticStatus.WARN, f"link: {snapshot.link_error}"
        else:
            level, message = DiagnosticStatus.OK, "output on" if c.output_enabled else "output off"
        values = {"port": c.port, "backend": backend, "channel_index": c.index,
                  "setpoint_v": c.setpoint, "measured_voltage_v": c.measured_voltage,
                  "measured_current_a": c.measured_current, "ceiling_v": c.ceiling,
                  "output_enabled": c.output_enabled, "faults": int(c.faults), "estop": snapshot.estop,
                  "link_error": snapshot.link_error}  # "" once the supply answers: a latched LINK may be reset
        statuses.append(DiagnosticStatus(level=level, name=f"{node_name}: channel {c.name}", message=message,
                                         hardware_id=snapshot.device_id,
                                         values=[KeyValue(key=k, value=str(v)) for k, v in values.items()]))
    return DiagnosticArray(header=Header(stamp=stamp), status=statuses)
