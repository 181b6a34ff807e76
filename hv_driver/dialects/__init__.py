"""Wire dialects of HV supplies. A new supply is one new module defining a `Dialect`."""
from .base import OPERATIONS, Command, Dialect, ProtocolError, StatusReport
from .iseg_edcp import IsegEdcp

__all__ = ["OPERATIONS", "Command", "Dialect", "IsegEdcp", "ProtocolError", "StatusReport"]
