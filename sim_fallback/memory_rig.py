"""The simulated supplies of one dialect inside the driver's own process, each behind a `MemoryPort`: every
command is answered within the driver's exchange, on the real clock, as by a supply with a processor of its own.
No simulation thread waits to be scheduled, so a loaded host (or a hypervisor that takes a virtual CPU away) never
makes the simulated supply answer late and trip the driver's LINK fault.

Same API as `SimulatedSupplyProcess` for what the supervisor needs: ``ports`` (port objects for `HvSupply`, one
per device), ``inject()``, ``clear_faults()``, ``stop()``. The supplies end with the process that holds them.
"""
from __future__ import annotations

from .memory_port import MemoryPort
from .pty_device import PtyDevice
from .rig import channels_per_device, check_address, make_devices


class MemoryRig:
    """dialect: which simulator (sim_fallback.rig.SIMULATORS); devices: how many; channels: per device, where the
    dialect has several."""

    def __init__(self, channels: int = 2, dialect: str = "iseg-edcp", devices: int = 1):
        self.dialect, self.channels = dialect, channels_per_device(dialect, channels)
        self.supplies: list[PtyDevice] = make_devices(dialect, devices, channels)
        self.ports = [MemoryPort(supply, name=f"memory:{dialect}/{k}") for k, supply in enumerate(self.supplies)]

    def start(self) -> MemoryRig:
        """Nothing to start (no thread, no pty); for the same use as `SimulatedSupplyProcess`."""
        return self

    def inject(self, fault: str, channel: int | None = None, device: int | None = None) -> None:
        """Inject ``fault`` (see ``sim_fallback.pty_device.FAULTS``) into a channel of a device (None: every one);
        ValueError for an unknown fault, channel or device."""
        check_address(channel, device, self.channels, len(self.supplies))
        for supply in self.supplies if device is None else [self.supplies[device]]:
            supply.inject(fault, channel)

    def clear_faults(self) -> None:
        for supply in self.supplies:
            supply.clear_faults()

    def stop(self) -> None:
        """Nothing to release: the supplies end with their process."""
