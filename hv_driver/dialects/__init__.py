"""Wire dialects of HV supplies. A new supply is one new module defining a `Dialect` (and its simulator)."""
from .base import (BASE_OPERATIONS, Capabilities, Command, CurrentSensing, DeviceSwitching, Dialect, ProtocolError,
                   StatusReport)
from .iseg_edcp import IsegEdcp

__all__ = ["BASE_OPERATIONS", "Capabilities", "Command", "CurrentSensing", "DeviceSwitching", "Dialect", "IsegEdcp",
           "ProtocolError", "StatusReport"]
