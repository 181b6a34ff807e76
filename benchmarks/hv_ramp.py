"""Two simulated channels ramped to 2.4 kV and back along minimum-jerk profiles (the gripper's smooth ramps).

Writes docs/figures/hv_ramp.png and docs/figures/hv_ramp.json.
    scripts/with_env.sh python benchmarks/hv_ramp.py
The back channel ramps first (opens the gripper), the front channel follows (grasp), both return
to 0 V; setpoints are streamed at 100 Hz by the driver and sampled here at 50 Hz.
"""
import json
import os
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hv_driver import ChannelConfig, HvSupply  # noqa: E402
from sim_fallback.hv_supply import SimulatedSupply  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "figures")
SLEW = 1000.0  # [V/s]
TARGET = 2400.0  # [V]
# (time after start [s], channel, target [V])
SCHEDULE = [(0.0, "back", TARGET), (2.0, "front", TARGET), (8.0, "back", 0.0), (10.0, "front", 0.0)]
DURATION = 15.0


def main() -> int:
    os.makedirs(FIGURES, exist_ok=True)
    configs = [ChannelConfig("front", 0, max_voltage_v=3000.0, slew_rate_v_per_s=SLEW),
               ChannelConfig("back", 1, max_voltage_v=3000.0, slew_rate_v_per_s=SLEW)]
    samples = []
    with SimulatedSupply(channels=2) as sim, HvSupply(sim.port, channels=configs, handle_signals=False) as hv:
        for name in ("front", "back"):
            hv.enable(name)
        token = hv.claim_control("hv_ramp benchmark")
        start, pending = time.monotonic(), list(SCHEDULE)
        while (now := time.monotonic() - start) < DURATION:
            while pending and pending[0][0] <= now:
                _, name, target = pending.pop(0)
                hv.ramp_to(name, target, token=token)
            hv.heartbeat(token)  # the watchdog ramps a silent client's outputs down
            snap = hv.snapshot()
            samples.append([snap.stamp - start] + [v for c in snap.channels for v in (c.setpoint, c.measured_voltage,
                                                                         c.measured_current)])
            if len(samples) % 50 == 0:
                print(f"ramp: {now:4.1f} / {DURATION:g} s", flush=True)
            time.sleep(0.02)
        faults = [int(c.faults) for c in hv.snapshot().channels]
    data = np.array(samples)
    data = data[np.unique(data[:, 0], return_index=True)[1]]  # one row per control cycle
    t = data[:, 0]
    result = {"command": "scripts/with_env.sh python benchmarks/hv_ramp.py", "slew_limit_v_per_s": SLEW,
              "target_v": TARGET, "faults": faults}
    fig, (ax_v, ax_i) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for k, (name, color) in enumerate((("front", "tab:blue"), ("back", "tab:orange"))):
        setpoint, measured, current = data[:, 1 + 3 * k], data[:, 2 + 3 * k], data[:, 3 + 3 * k]
        rate = np.diff(setpoint) / np.diff(t)
        result[name] = {"peak_setpoint_v": float(setpoint.max()), "peak_measured_v": float(measured.max()),
                        "peak_rate_v_per_s": float(np.abs(rate).max()),
                        "max_tracking_error_v": float(np.abs(measured - setpoint).max()),
                        "peak_current_a": float(current.max())}
        ax_v.plot(t, setpoint / 1e3, color=color, ls="--", lw=1, label=f"{name} setpoint")
        ax_v.plot(t, measured / 1e3, color=color, lw=2, alpha=0.6, label=f"{name} measured")
        ax_i.plot(t, current * 1e6, color=color, label=name)
    ax_v.set(ylabel="voltage [kV]", title=f"smooth ramps to {TARGET / 1e3:g} kV and back (slew limit {SLEW:g} V/s)")
    ax_v.legend(fontsize=8, ncol=2)
    ax_i.set(xlabel="time [s]", ylabel="supply current [µA]", title="charging current C·dV/dt + leakage")
    ax_i.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(FIGURES, "hv_ramp.png"), dpi=120)
    with open(os.path.join(FIGURES, "hv_ramp.json"), "w") as stream:
        json.dump(result, stream, indent=2)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
