"""One PNG per recording: voltage, current, step timeline and predicted (lines) against estimated (dots) block
angles."""
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend chosen first: no display needed)

from .analysis import RecordingData, step_durations  # noqa: E402

OUTCOME_COLOURS = {"succeeded": "tab:green", "failed": "tab:red", "canceled": "tab:orange",
                   "unfinished": "tab:gray"}


def plot(data: RecordingData, png_path: str, title: str = "") -> None:
    """Writes the four stacked panels (shared time axis) with fault events marked."""
    figure, (voltage, current, steps, angles) = plt.subplots(
        4, 1, sharex=True, figsize=(10, 10), height_ratios=[3, 2, 2, 3])
    for name, series in sorted(data.hv.items()):
        line, = voltage.plot(series["time"], [v / 1e3 for v in series["voltage"]],
                             label=f"{name} measured")
        voltage.plot(series["time"], [v / 1e3 for v in series["setpoint"]], "--",
                     color=line.get_color(), alpha=0.6, label=f"{name} setpoint")
        current.plot(series["time"], [i * 1e6 for i in series["current"]], label=name)
    voltage.set_ylabel("voltage [kV]")
    current.set_ylabel("current [µA]")
    _mark_faults((voltage, current), data.faults)
    _plot_steps(steps, step_durations(data.events), data.duration)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for number, (name, series) in enumerate(sorted(data.angles.items())):
        colour = colours[number % len(colours)]
        _plot_blocks(angles, series, "-", colour, f"{name} ({_width(series)} blocks)")
        if name in data.estimated:
            _plot_blocks(angles, data.estimated[name], ".", colour, f"{name} estimated")
    angles.set_ylabel("block angle [deg]\npredicted (lines), estimated (dots)")
    angles.set_xlabel("time [s]")
    for axis in (voltage, current, angles):
        if axis.get_legend_handles_labels()[0]:
            axis.legend(fontsize=7, loc="best", ncols=2)
        axis.grid(alpha=0.3)
    figure.suptitle(title or "recording")
    figure.tight_layout()
    figure.savefig(png_path, dpi=110)
    plt.close(figure)


def _width(series: dict) -> int:
    return max(len(a) for a in series["angles"])


def _plot_blocks(axis, series: dict, style: str, colour: str, label: str) -> None:
    """One line (or dot series) per block position of a chain's angle series, in degrees."""
    for block in range(_width(series)):
        axis.plot(series["time"], [math.degrees(a[block]) if block < len(a) else math.nan for a in series["angles"]],
                  style, color=colour, markersize=4, label=label if block == 0 else None)


def _mark_faults(axes, faults: list[dict]) -> None:
    """A vertical line per fault event; channels raising the same bits at once share one label."""
    grouped: dict = {}
    for fault in faults:
        key = (round(fault["time"], 3), fault["event"], ",".join(fault["faults"]))
        grouped.setdefault(key, []).append(fault["channel"])
    for (time, event, names), channels in grouped.items():
        colour = "tab:red" if event == "raised" else "tab:blue"
        for axis in axes:
            axis.axvline(time, color=colour, linestyle=":", linewidth=1)
        axes[0].annotate(f"{event} {names}: {', '.join(channels)}", (time, 1),
                         xycoords=("data", "axes fraction"), rotation=90, va="top",
                         fontsize=7, color=colour)


def _plot_steps(axis, steps: list[dict], duration: float) -> None:
    for row, step in enumerate(steps):
        end = step["end"] if step["end"] is not None else duration
        axis.broken_barh([(step["start"], max(end - step["start"], 1e-3))], (row - 0.4, 0.8),
                         color=OUTCOME_COLOURS.get(step["outcome"], "tab:gray"))
    axis.set_yticks(range(len(steps)), [f"{s['step_index']} {s['step_name']}" for s in steps],
                    fontsize=7)
    axis.invert_yaxis()
    axis.set_ylabel("sequence step")
    axis.grid(alpha=0.3, axis="x")
