"""An in-memory serial link between the driver and a simulated supply: no pty, no thread.

`MemoryPort(device)` is a pyserial-like port (``write``, ``read``, ``readline``, ``in_waiting``,
``reset_input_buffer``, ``timeout``) whose every write is answered at once by ``device.feed`` on the device's
clock, in the writer's own thread. A device that stays silent makes a read wait its timeout on that clock, as a
real port would.

- On a `hv_driver.clock.SimulatedClock` shared with `HvSupply`, the whole loop runs in simulated time;
  ``exchange_s`` is the simulated time one line takes on the wire (each write advances the clock by it), so a
  cycle of many exchanges takes time as on a real port.
- On the real clock, it is a supply with a processor of its own: no thread of the simulation waits to be
  scheduled, so a host that deschedules the simulation (load, a hypervisor taking the virtual CPU) never makes
  it answer late, as a simulator on a pty can.
"""
from .pty_device import PtyDevice


class MemoryPort:
    def __init__(self, device: PtyDevice, exchange_s: float = 0.0, name: str | None = None):
        self.device, self.exchange_s = device, exchange_s
        self.name = name or f"memory:{type(device).__name__}@{id(device):x}"
        self.timeout: float = 0.1
        self._buffer = bytearray()

    def write(self, data: bytes) -> int:
        if not self.device.connected:
            raise OSError(5, "Input/output error (the cable is pulled)")
        if self.exchange_s:
            self.device.clock.sleep(self.exchange_s)
        self._buffer += self.device.feed(bytes(data))
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes; with nothing to read, the wait of a real port: its timeout, on the clock."""
        if not self.device.connected:
            raise OSError(5, "Input/output error (the cable is pulled)")
        if not self._buffer:
            self.device.clock.sleep(self.timeout)
            self.device.poll()
            return b""
        chunk = bytes(self._buffer[:size])
        del self._buffer[:size]
        return chunk

    def readline(self) -> bytes:
        """Bytes up to and including the next line feed; as pyserial, what came before a read timed out."""
        line = b""
        while not line.endswith(b"\n") and (byte := self.read(1)):
            line += byte
        return line

    def reset_input_buffer(self) -> None:
        self._buffer.clear()

    def close(self) -> None:
        """Nothing to release (the port may be opened again)."""
