"""HV supply driver with a safety supervisor (no ROS).

Public API: `HvSupply` (driver), `ChannelConfig` (per-channel limits), `DIALECTS` / `dialect(name)` (the supplies
it speaks), `Fault` (latched fault
bits, equal to HvChannelState.msg), `SupplySnapshot` / `ChannelSnapshot`, `RampHandle`, `PulseHandle` (periodic actuation), and the
errors, all `HvError`: `SettingError` (and its `LimitError`), `StateError`, `FaultLatchedError`,
`ConfigurationError`, `LinkError`, `ProtocolError`, `PulseLimitError` (a waveform the supply cannot produce),
`SupervisorLostError`. `RemoteSupply`: the same API served by the supervisor process (`hv_driver.server`).
"""
from .config import ChannelConfig
from .control import ControlError
from .dialects import DIALECTS, Dialect, IsegEdcp, ProtocolError, dialect
from .driver import ChannelSnapshot, ConfigurationError, HvSupply, PulseHandle, RampHandle, SupplySnapshot
from .pulse import PulseLimitError
from .errors import HvError, SettingError, StateError
from .faults import Fault, fault_names
from .link import LinkError
from .remote import RemoteSupply, SupervisorLostError
from .supervisor import FaultLatchedError, LimitError, Supervisor

__all__ = ["ChannelConfig", "ChannelSnapshot", "ConfigurationError", "ControlError", "DIALECTS", "Dialect", "Fault",
           "FaultLatchedError", "HvError", "HvSupply", "IsegEdcp", "LimitError", "LinkError", "ProtocolError",
           "PulseHandle", "PulseLimitError", "RampHandle", "RemoteSupply", "SettingError", "StateError", "Supervisor", "SupervisorLostError", "SupplySnapshot", "dialect", "fault_names"]
