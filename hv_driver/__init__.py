"""HV supply driver with a safety supervisor (no ROS).

Public API: `HvSupply` (driver), `ChannelConfig` (per-channel limits), `DIALECTS` / `dialect(name)` (the supplies
it speaks), `Fault` (latched fault
bits, equal to HvChannelState.msg), `SupplySnapshot` / `ChannelSnapshot`, `RampHandle`, and the
errors, all `HvError`: `SettingError` (and its `LimitError`), `StateError`, `FaultLatchedError`,
`ConfigurationError`, `LinkError`, `ProtocolError`.
"""
from .config import ChannelConfig
from .control import ControlError
from .dialects import DIALECTS, Dialect, IsegEdcp, ProtocolError, dialect
from .driver import ChannelSnapshot, ConfigurationError, HvSupply, RampHandle, SupplySnapshot
from .errors import HvError, SettingError, StateError
from .faults import Fault, fault_names
from .link import LinkError
from .supervisor import FaultLatchedError, LimitError, Supervisor

__all__ = ["ChannelConfig", "ChannelSnapshot", "ConfigurationError", "ControlError", "DIALECTS", "Dialect", "Fault",
           "FaultLatchedError", "HvError", "HvSupply", "IsegEdcp", "LimitError", "LinkError", "ProtocolError",
           "RampHandle", "SettingError", "StateError", "Supervisor", "SupplySnapshot", "dialect", "fault_names"]
