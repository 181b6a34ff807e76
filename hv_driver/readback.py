"""Readback check of one output: where the output should be, and for how long it has been elsewhere.

Pure logic, time passed in. A supply with a ramp of its own (iseg: `:CONF:RAMP:VOLT`, and `:VOLT OFF`
ramps down at it) moves its output towards each commanded voltage at that rate, so a readback taken just
after a new setpoint, after a stalled control cycle, or while the device ramps down an output switched
off lags the command by what the ramp allows. The expected voltage follows the commands at the device
rate; a readback between it and the command (± tolerance) is consistent. A voltage falling at the device
rate is no fault; one that does not fall is.

The time off the expectation counts only what the loop observed: each interval between two readbacks adds
at most one period the loop sustains, so a stall of the loop is not counted as time off (the count resumes after
the gap, as if restarted), while a loop that keeps running late still trips, later by its lateness.
"""


class ReadbackCheck:
    """tolerance_v, time_limit_s: a readback further than tolerance_v from the expectation for longer than
    time_limit_s is a mismatch. max_interval_s: the most one interval between readbacks adds to that time
    (the period the loop sustains, `hv_driver.supervisor.Supervisor.set_cycle_period`). ramp_rate_v_per_s: the device's own ramp, None when it has none (the
    output follows each command at once)."""

    def __init__(self, tolerance_v: float, time_limit_s: float, max_interval_s: float, now: float = 0.0):
        self.tolerance_v, self.time_limit_s, self.max_interval_s = tolerance_v, time_limit_s, max_interval_s
        self.ramp_rate_v_per_s: float | None = None
        self.commanded = 0.0  # [V] what the device was last told (0 V when off)
        self.expected = 0.0   # [V] where a device ramping at ramp_rate would be now
        self._since = now     # time of the last command or readback the expectation was advanced to
        self._last_readback: float | None = None
        self._switching = False  # the device switches by itself (see `switching`)
        self.off_for = 0.0    # [s] observed time off the expectation, counted from the first readback off it
        self._off = False

    def _advance(self, now: float) -> None:
        if self._switching:  # anywhere from 0 V (expected) to the amplitude (commanded) fits
            self._since = max(self._since, now)
            return
        if self.ramp_rate_v_per_s is None:
            self.expected = self.commanded
        else:
            reach = self.ramp_rate_v_per_s * max(0.0, now - self._since)
            self.expected += max(-reach, min(reach, self.commanded - self.expected))
        self._since = max(self._since, now)

    def command(self, now: float, voltage: float, ramped: bool = True) -> None:
        """The device is told ``voltage`` at ``now``; ``ramped`` False: it drops without ramp (emergency off)."""
        if self._switching:  # the device stops switching: its output falls from at most the amplitude
            self._switching, self.expected = False, self.commanded
        self._advance(now)
        self.commanded = voltage
        if not ramped:
            self.expected = voltage

    def switching(self, now: float, amplitude: float) -> None:
        """The device switches its output between 0 V and ``amplitude`` by itself: any readback in between fits
        until the next `command`."""
        self._advance(now)
        self.commanded, self.expected, self._switching = amplitude, 0.0, True

    def found(self, now: float, voltage: float) -> None:
        """The output was found at ``voltage`` (at open: left on by an earlier session); it ramps from there."""
        self._since = now
        self.expected = voltage

    def band(self) -> tuple[float, float]:
        """Consistent readbacks lie between these voltages [V]."""
        low, high = sorted((self.expected, self.commanded))
        return low - self.tolerance_v, high + self.tolerance_v

    def check(self, now: float, measured: float) -> str | None:
        """Check one readback; the reason of a mismatch once it has lasted longer than time_limit_s."""
        self._advance(now)
        low, high = self.band()
        interval = 0.0 if self._last_readback is None else max(0.0, now - self._last_readback)
        self._last_readback = now
        if low <= measured <= high:
            self.off_for, self._off = 0.0, False
            return None
        self.off_for = self.off_for + min(interval, self.max_interval_s) if self._off else 0.0
        self._off = True
        if self.off_for <= self.time_limit_s:
            return None
        ramp = ("at once" if self.ramp_rate_v_per_s is None
                else f"at the device ramp of {self.ramp_rate_v_per_s:g} V/s")
        return (f"measured {measured:.1f} V, commanded {self.commanded:.1f} V (expected {self.expected:.1f} V, "
                f"following {ramp}) for more than {self.time_limit_s:g} s")

    def reset(self) -> None:
        self.off_for, self._off = 0.0, False
