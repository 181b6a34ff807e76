"""Wire dialects of HV supplies. A new supply is one new module defining a `Dialect` (and its simulator in
sim_fallback), listed in DIALECTS."""
from .base import (BASE_OPERATIONS, Capabilities, Command, CurrentSensing, DeviceSwitching, Dialect, ProtocolError,
                   StatusReport)
from .iseg_edcp import IsegEdcp
from .keithley_2290 import Keithley2290
from .ppv import PetaPicoVoltron

DIALECTS: dict[str, type[Dialect]] = {cls.name: cls for cls in (IsegEdcp, Keithley2290, PetaPicoVoltron)}


def dialect(name: str) -> Dialect:
    """The dialect called ``name`` (ValueError naming the known ones)."""
    try:
        return DIALECTS[name]()
    except KeyError:
        raise ValueError(f"dialect={name!r}: one of {', '.join(DIALECTS)}") from None


__all__ = ["BASE_OPERATIONS", "Capabilities", "Command", "CurrentSensing", "DIALECTS", "DeviceSwitching", "Dialect",
           "IsegEdcp", "Keithley2290", "PetaPicoVoltron", "ProtocolError", "StatusReport", "dialect"]
