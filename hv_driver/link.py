"""Line framing over a serial port: write a command, check its echo (if the device echoes), read the answer line
(if the operation has one)."""
import termios

import serial

from .clock import MONOTONIC
from .dialects import Dialect, ProtocolError
from .errors import HvError

# Longest line the driver accepts; anything longer is garbage.
MAX_LINE = 256
# After a failed exchange the line must fall quiet within this many reply timeouts, or the link fails.
RESYNC_WINDOWS = 4
RESYNC_POLL = 0.002  # [s]


class LinkError(HvError, ConnectionError):
    """No reply, a partial reply within the timeout, or the port failed."""


class Link:
    """One command/answer exchange at a time over a pyserial-like port.

    After any failed exchange the next one first resynchronises: it discards what is buffered and whatever
    still arrives until the line has been quiet for one reply timeout, so an answer that came late (a
    device or host descheduled past the timeout) is not taken for the answer to the next command. A dialect
    without echo has no other way to tell answers apart. An answer later than that window is not caught
    here; the dialect's decoding and the echo (where there is one) still refuse most mismatches.
    """

    def __init__(self, port, dialect: Dialect, reply_timeout: float, clock=MONOTONIC):
        self.port = port
        self.clock = clock  # deadlines and the resync's polling (a `hv_driver.clock` clock)
        self.dialect = dialect
        self.reply_timeout = reply_timeout
        self._buffer = bytearray()
        self._stale = False

    def query(self, operation: str, channels=(), value: float | None = None):
        """Run ``operation`` and return its decoded answer (see `Dialect.decode`)."""
        line = self.dialect.encode(operation, channels, value)
        try:
            reply = self._exchange(line, self.dialect.expects_reply(operation))
            return None if reply is None else self.dialect.decode(operation, reply, max(1, len(channels)), line)
        except (LinkError, ProtocolError):
            self._stale = True
            raise

    @property
    def stale(self) -> bool:
        """The last exchange failed: the next one first waits for the line to fall quiet (`_resync`)."""
        return self._stale

    def send(self, operation: str, channels=(), value: float | None = None) -> None:
        """Write ``operation`` at once, without waiting for the line to fall quiet or reading its answer (which the
        next exchange's resynchronisation discards): a cut that must not wait a reply timeout behind a failed
        exchange. Nothing is learnt from it; the device's status confirms what it did."""
        line = self.dialect.encode(operation, channels, value)
        self._stale = True
        self._call(self.port.write, line.encode("ascii") + self.dialect.command_terminator)

    def _exchange(self, line: str, answered: bool) -> str | None:
        if self._stale:
            self._resync(line)
            self._stale = False
        self._call(self.port.write, line.encode("ascii") + self.dialect.command_terminator)
        deadline = self.clock() + self.reply_timeout
        if self.dialect.echo:
            echo = self._read_line(deadline, line)
            if echo != line:
                raise ProtocolError(f"wrong echo {echo!r} for {line!r}")
        return self._read_line(deadline, line) if answered else None

    def _resync(self, line: str) -> None:
        self.discard_input(f"after a failed exchange; {line!r} not sent")

    def discard_input(self, context: str = "") -> None:
        """Drop what is buffered and whatever still arrives until the line has been quiet for one reply timeout;
        LinkError (naming ``context``) if it keeps sending for RESYNC_WINDOWS reply timeouts."""
        self._buffer.clear()
        self._call(self.port.reset_input_buffer)
        start = quiet_since = self.clock()
        while (now := self.clock()) - quiet_since < self.reply_timeout:
            if now - start > RESYNC_WINDOWS * self.reply_timeout:
                raise LinkError(f"the device kept sending for {now - start:.3g} s {context}".rstrip())
            waiting = self._call(lambda: self.port.in_waiting)
            if waiting:
                self._call(self.port.read, waiting)
                quiet_since = self.clock()
            else:
                self.clock.sleep(RESYNC_POLL)

    def _read_line(self, deadline: float, line: str) -> str:
        terminator = self.dialect.reply_terminator
        while (end := self._buffer.find(terminator)) < 0:
            if len(self._buffer) > MAX_LINE:
                raise ProtocolError(f"reply to {line!r} longer than {MAX_LINE} bytes without terminator")
            waiting = self._call(lambda: self.port.in_waiting)
            if self.clock() >= deadline and not waiting:
                # Bytes that arrived while this host was descheduled past the deadline still count: only
                # a device that has sent nothing more by the deadline is late.
                what = f"partial reply {bytes(self._buffer)!r}" if self._buffer else "no reply"
                raise LinkError(f"{what} to {line!r} within {self.reply_timeout:g} s")
            self._buffer += self._call(self.port.read, max(1, waiting))
        raw = bytes(self._buffer[:end]).rstrip(b"\r")  # a CR before an LF terminator is part of the line end
        del self._buffer[: end + len(terminator)]
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(f"non-ASCII reply {raw!r} to {line!r}") from None

    @staticmethod
    def _call(function, *args):
        try:
            return function(*args)
        except (serial.SerialException, OSError, termios.error) as error:
            raise LinkError(f"serial port failed: {error}") from error
