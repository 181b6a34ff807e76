"""HV supply driver with a safety supervisor (no ROS).

Public API: `HvSupply` (driver), `ChannelConfig` (per-channel limits), `Fault` (latched fault
bits, equal to HvChannelState.msg), `SupplySnapshot` / `ChannelSnapshot`, `RampHandle`, and the
errors, all `HvError`: `SettingError` (and its `LimitError`), `StateError`, `FaultLatchedError`,
`ConfigurationError`, `LinkError`, `ProtocolError`.
"""
from .config import ChannelConfig
from .control import ControlError
from .dialects import Dialect, IsegEdcp, ProtocolError
from .driver import ChannelSnapshot, ConfigurationError, HvSupply, RampHandle, SupplySnapshot
from .errors import HvError, SettingError, StateError
from .faults import Fault, fault_names
from .link import LinkError
from .supervisor import FaultLatchedError, LimitError, Supervisor

__all__ = ["ChannelConfig", "ChannelSnapshot", "ConfigurationError", "ControlError", "Dialect", "Fault",
           "FaultLatchedError", "HvError", "HvSupply", "IsegEdcp", "LimitError", "LinkError", "ProtocolError",
           "RampHandle", "SettingError", "StateError", "Supervisor", "SupplySnapshot", "fault_names"]
