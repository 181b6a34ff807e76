"""Simulated supplies of one dialect as one process: a rig of one or more devices, each on its own pty, driven
from stdin (one line in, one line out).

    python -m sim_fallback.rig --dialect ppv --devices 4   # prints one pty path per device, then reads:
    over_current 0 device=2   # inject a fault (channel and device optional: every one), answers "ok"
    watch 0 300 device=1      # record the rising crossings of 300 V by channel 0 of device 1
    edges 0 device=1          # those crossings so far (time.monotonic of this machine), comma-separated
    status | clear | quit
"""
import argparse
import sys

from hv_driver.realtime import DEFAULT_PRIORITY, fifo

from .hv_plant import ChannelDefaults
from .hv_supply import SimulatedSupply
from .keithley_supply import SimulatedKeithley2290
from .ppv_supply import SimulatedPpv
from .pty_device import PtyDevice

# A real supply has a processor of its own, so load on the host never makes it answer late. The simulation takes
# real-time priority where the host grants it (below the supervisor's), else runs as it is.
SIMULATED_DEVICE_PRIORITY = DEFAULT_PRIORITY - 1

SIMULATORS: dict[str, type[PtyDevice]] = {cls.dialect.name: cls
                                          for cls in (SimulatedSupply, SimulatedKeithley2290, SimulatedPpv)}


def simulator(dialect: str) -> type[PtyDevice]:
    try:
        return SIMULATORS[dialect]
    except KeyError:
        raise ValueError(f"dialect={dialect!r}: simulated are {', '.join(SIMULATORS)}") from None


def channels_per_device(dialect: str, requested: int | None = None) -> int:
    """Channels of one simulated device: fixed by the dialect, or ``requested`` (default 4) where it reports them."""
    fixed = simulator(dialect).dialect.capabilities.channels_per_device
    return fixed if fixed is not None else (requested or 4)


def check_address(channel: int | None, device: int | None, channels: int, devices: int) -> None:
    """ValueError naming a ``channel`` or ``device`` (None: every one) outside a rig of ``devices`` supplies of
    ``channels`` channels."""
    if channel is not None and not (isinstance(channel, int) and 0 <= channel < channels):
        raise ValueError(f"channel={channel!r}: between 0 and {channels - 1}")
    if device is not None and not (isinstance(device, int) and 0 <= device < devices):
        raise ValueError(f"device={device!r}: between 0 and {devices - 1}")


def make_devices(dialect: str, devices: int, channels: int | None = None, voltage_limit: float | None = None,
                 watchdog_s: float | None = None) -> list[PtyDevice]:
    """``devices`` simulated supplies of ``dialect`` (not started), each with its own noise seed; ``channels``
    per device where the dialect has several; ``voltage_limit`` [V] replaces the dialect's hardware limit."""
    if devices < 1 or (channels is not None and channels < 1):
        raise ValueError(f"channels={channels}, devices={devices}: at least 1 each")
    cls = simulator(dialect)
    defaults = cls.default_defaults
    if voltage_limit is not None:
        defaults = ChannelDefaults(**{**defaults.__dict__, "voltage_limit": voltage_limit})
    return [cls(channels_per_device(dialect, channels), defaults, watchdog_s=watchdog_s, rng=k)
            for k in range(devices)]


def _command(devices: list[PtyDevice], words: list[str]) -> str:
    """Run one stdin command; returns its answer line (ValueError for a bad one)."""
    device = next((w for w in words if w.startswith("device=")), None)
    words = [w for w in words if w != device]
    chosen = devices if device is None else [devices[_index(device.removeprefix("device="), len(devices), "device")]]
    verb, args = words[0], words[1:]
    if verb == "clear":
        for d in chosen:
            d.clear_faults()
        return "ok"
    if verb == "status":
        return " | ".join(d.status_text() for d in chosen)
    if verb == "watch":
        for d in chosen:
            d.watch(int(args[0]), float(args[1]))
        return "ok"
    if verb == "edges":
        return ",".join(f"{t:.6f}" for d in chosen for t in d.edges(int(args[0])))
    for d in chosen:
        d.inject(verb, int(args[0]) if args else None)
    return "ok"


def _index(text: str, count: int, what: str) -> int:
    value = int(text)
    if not 0 <= value < count:
        raise ValueError(f"{what}={value}: between 0 and {count - 1}")
    return value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dialect", default=SimulatedSupply.dialect.name, choices=sorted(SIMULATORS))
    parser.add_argument("--devices", type=int, default=1, help="devices (ports) of the rig")
    parser.add_argument("--channels", type=int, default=None, help="channels per device where the dialect has several")
    parser.add_argument("--voltage-limit", type=float, default=None, help="[V] hardware limit")
    parser.add_argument("--watchdog", type=float, default=0.0, help="host keep-alive [s]; 0 (default) = none")
    args = parser.parse_args(argv)
    fifo(SIMULATED_DEVICE_PRIORITY)  # before the devices' threads start, which inherit it
    devices = [device.start() for device in make_devices(args.dialect, args.devices, args.channels,
                                                           args.voltage_limit, args.watchdog or None)]
    for device in devices:
        print(device.port, flush=True)
    try:
        for line in sys.stdin:
            words = line.split()
            if not words:
                continue
            if words[0] == "quit":
                break
            try:
                print(_command(devices, words), flush=True)
            except (ValueError, IndexError) as error:
                print(f"error: {error}", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        for device in devices:
            device.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
