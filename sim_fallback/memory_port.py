"""An in-memory serial link between the driver and a simulated supply: no pty, no thread.

`MemoryPort(device)` is a pyserial-like port (``write``, ``read``, ``readline``, ``in_waiting``,
``reset_input_buffer``, ``timeout``) whose every write is answered at once by ``device.feed`` on the device's
clock. Given to `HvSupply` with the same `hv_driver.clock.SimulatedClock`, the whole loop runs in simulated time: a
device that stays silent makes a read wait its timeout on that clock, as a real port would; ``exchange_s`` is the
simulated time one line takes on the wire (each write advances the clock by it), so a cycle of many exchanges takes
time as on a real port.
"""
from .pty_device import PtyDevice


class MemoryPort:
    def __init__(self, device: PtyDevice, exchange_s: float = 0.0, name: str | None = None):
        if not device.clock.simulated:
            raise ValueError("MemoryPort: the device must run on a SimulatedClock (a real-time device needs a pty)")
        self.device, self.exchange_s = device, exchange_s
        self.name = name or f"memory:{type(device).__name__}@{id(device):x}"
        self.timeout: float = 0.1
        self._buffer = bytearray()

    def write(self, data: bytes) -> int:
        if not self.device.connected:
            raise OSError(5, "Input/output error (the cable is pulled)")
        self.device.clock.advance(self.exchange_s)
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
            self.device.clock.advance(self.timeout)
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
