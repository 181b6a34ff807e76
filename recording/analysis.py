"""Grasp review from a recording, without ROS running: voltages, steps, predicted and estimated shape, faults,
and the samples each topic lost on the way to the recorder (recording.gaps).

Reads with `mcap` + `mcap-ros2-support` (the schemas inside the file), never imports rclpy.
Topics are found by message type, so namespaced stacks are analysed the same way. Times are in
seconds from the first analysed message, taken from header stamps (log time when a stamp is 0).
AssemblyState on a topic ending in ``assembly/estimated`` is the estimate from camera images, any other the
prediction.
"""
import bisect
import math
import re
import statistics
from collections import defaultdict
from dataclasses import dataclass, field

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from .bounded_mcap import open_bounded, undecodable
from .gaps import checkable, find_gaps
from .mcap_file import require_complete

HV_STATE = "softblock_interfaces/msg/HvState"
SEQUENCE_EVENT = "softblock_interfaces/msg/SequenceEvent"
ASSEMBLY_STATE = "softblock_interfaces/msg/AssemblyState"
ANALYSED_TYPES = (HV_STATE, SEQUENCE_EVENT, ASSEMBLY_STATE)
ESTIMATED_TOPIC = "assembly/estimated"
TERMINAL_PHASES = ("succeeded", "failed", "canceled")
_FAULT_CONSTANT = re.compile(r"^\s*uint32\s+FAULT_([A-Z0-9_]+)\s*=\s*(\d+)", re.MULTILINE)


@dataclass
class RecordingData:
    """Time series pulled out of a recording; times in seconds since its first analysed stamp."""

    hv: dict = field(default_factory=lambda: defaultdict(lambda: defaultdict(list)))
    events: list = field(default_factory=list)
    angles: dict = field(default_factory=lambda: defaultdict(lambda: defaultdict(list)))  # predicted
    estimated: dict = field(default_factory=lambda: defaultdict(lambda: defaultdict(list)))  # from images
    faults: list = field(default_factory=list)
    message_counts: dict = field(default_factory=dict)
    fault_names: dict = field(default_factory=dict)
    lost_samples: dict = field(default_factory=dict)
    duration: float = 0.0


def _stamp_ns(message, log_time: int) -> int:
    stamp = message.header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec or log_time


def fault_names(bits: int, names: dict) -> list[str]:
    """FAULT_* names of the set bits, lowest bit first."""
    return [names.get(1 << i, f"bit{i}") for i in range(32) if bits & (1 << i)]


def load(path: str) -> RecordingData:
    """Decodes the HvState, SequenceEvent and AssemblyState messages of `path`."""
    with undecodable(path):
        return _load(path)


def _load(path: str) -> RecordingData:
    require_complete(path)
    data = RecordingData()
    rows = []
    with open_bounded(path) as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for schema in summary.schemas.values():
            if schema.name == HV_STATE:
                data.fault_names = {int(value): name.lower() for name, value
                                    in _FAULT_CONSTANT.findall(schema.data.decode())}
        wanted = [c.topic for c in summary.channels.values() if c.schema_id in summary.schemas
                  and summary.schemas[c.schema_id].name in ANALYSED_TYPES]
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=wanted):
            rows.append((_stamp_ns(decoded, message.log_time), schema.name, decoded, channel.topic))
            data.message_counts[channel.topic] = data.message_counts.get(channel.topic, 0) + 1
        numbered = defaultdict(list)
        for _, channel, message in reader.iter_messages():  # in receive order
            numbered[channel.topic].append((message.sequence, message.publish_time))
    if not rows:
        return data
    rows.sort(key=lambda row: row[0])
    origin = rows[0][0]
    data.lost_samples = _lost_samples(summary.channels.values(), numbered, origin)
    data.duration = (rows[-1][0] - origin) / 1e9
    latched_faults: dict[str, int] = {}
    for stamp, type_name, message, topic in rows:
        t = (stamp - origin) / 1e9
        if type_name == HV_STATE:
            _add_hv_state(data, t, message, latched_faults)
        elif type_name == SEQUENCE_EVENT:
            data.events.append({"time": t, "sequence": message.sequence,
                                "step_index": message.step_index,
                                "step_name": message.step_name, "phase": message.phase,
                                "message": message.message})
        else:
            series = data.estimated if topic.endswith(ESTIMATED_TOPIC) else data.angles
            for chain in message.chains:
                series[chain.name]["time"].append(t)
                series[chain.name]["angles"].append(list(chain.block_angles))
    return data


def _lost_samples(channels, numbered: dict, origin: int) -> dict:
    """Per topic: the gaps in its publication sequence numbers (times in s from ``origin``), or why not checked."""
    report = {}
    for channel in sorted(channels, key=lambda c: c.topic):
        reason = checkable(channel.metadata.get("offered_qos_profiles", ""), channel.topic)
        if reason:
            report[channel.topic] = {"checked": False, "reason": reason}
            continue
        found = find_gaps(numbered.get(channel.topic, []))
        if found["interleaved"]:
            report[channel.topic] = {"checked": False, "reason": "the numbers interleave (a publisher joined later)"}
            continue
        gaps = [{"after": g["after"], "before": g["before"], "lost": g["lost"],
                 "from": (g["after_time_ns"] - origin) / 1e9, "to": (g["before_time_ns"] - origin) / 1e9}
                for g in found["gaps"]]
        report[channel.topic] = {"checked": True, "received": found["received"], "lost": found["lost"],
                                 "gaps": gaps}
    return report


def _add_hv_state(data: RecordingData, t: float, message, latched_faults: dict) -> None:
    for channel in message.channels:
        series = data.hv[channel.name]
        series["time"].append(t)
        series["voltage"].append(channel.measured_voltage)
        series["current"].append(channel.measured_current)
        series["setpoint"].append(channel.setpoint)
        previous = latched_faults.get(channel.name, 0)
        raised = channel.faults & ~previous
        if raised or (previous and not channel.faults):
            data.faults.append({
                "time": t, "channel": channel.name, "event": "raised" if raised else "cleared",
                "bits": raised or previous,
                "faults": fault_names(raised or previous, data.fault_names),
                "fault_text": channel.fault_text})
        latched_faults[channel.name] = channel.faults


def step_durations(events: list[dict]) -> list[dict]:
    """Pairs each 'started' event with the next terminal event of the same step."""
    steps, running = [], {}
    for event in events:
        key = (event["sequence"], event["step_index"])
        if event["phase"] == "started":
            running[key] = {"sequence": event["sequence"], "step_index": event["step_index"],
                            "step_name": event["step_name"], "start": event["time"],
                            "end": None, "duration": None, "outcome": "unfinished",
                            "message": ""}
            steps.append(running[key])
        elif event["phase"] in TERMINAL_PHASES and key in running:
            step = running.pop(key)
            step.update(end=event["time"], duration=event["time"] - step["start"],
                        outcome=event["phase"], message=event["message"])
    return steps


def summarize(data: RecordingData) -> dict:
    """Peak voltage/current per channel, step durations, faults, final predicted angles."""
    channels = {}
    for name, series in sorted(data.hv.items()):
        peak = max(range(len(series["voltage"])), key=series["voltage"].__getitem__)
        channels[name] = {"peak_voltage": series["voltage"][peak],
                          "peak_voltage_time": series["time"][peak],
                          "peak_current": max(series["current"], key=abs),
                          "samples": len(series["time"])}
    chains = {}
    for name, series in sorted(data.angles.items()):
        final = series["angles"][-1]
        same_shape = [a for a in series["angles"] if len(a) == len(final)]
        chains[name] = {"final_angles": final,
                        "min_angles": [min(column) for column in zip(*same_shape)],
                        "max_angles": [max(column) for column in zip(*same_shape)],
                        "samples": len(series["time"])}
    estimated = {name: {"final_angles": series["angles"][-1], "samples": len(series["time"]),
                        "median_minus_predicted": estimate_minus_prediction(data.angles.get(name), series)}
                 for name, series in sorted(data.estimated.items())}
    return {"duration": data.duration, "message_counts": dict(sorted(data.message_counts.items())),
            "channels": channels, "hv_state_longest_silence": longest_silence(data.hv),
            "steps": step_durations(data.events), "faults": data.faults,
            "chains": chains, "estimated_chains": estimated,
            "lost_samples": {topic: report for topic, report in data.lost_samples.items()
                             if report["checked"] and report["lost"]}}


def longest_silence(hv: dict) -> dict | None:
    """The longest time between two hv/state messages (by the driver's stamps: how long it published nothing)
    and when it began [s]; None with fewer than two messages."""
    times = sorted({t for series in hv.values() for t in series["time"]})
    if len(times) < 2:
        return None
    start = max(range(len(times) - 1), key=lambda i: times[i + 1] - times[i])
    return {"seconds": times[start + 1] - times[start], "from": times[start]}


def estimate_minus_prediction(predicted: dict | None, estimated: dict) -> list[float] | None:
    """Per block, the median of estimated minus predicted angle [rad], each estimate paired with the last
    prediction at or before it (of the same block count); None without such pairs."""
    if not predicted:
        return None
    differences = []
    for t, angles in zip(estimated["time"], estimated["angles"]):
        index = bisect.bisect_right(predicted["time"], t) - 1
        if index >= 0 and len(predicted["angles"][index]) == len(angles):
            differences.append([e - p for e, p in zip(angles, predicted["angles"][index])])
    return [statistics.median(column) for column in zip(*differences)] if differences else None


def analyze(recording: str) -> dict:
    """Summary dict of one recording: compare analyze(original) with analyze(replay)."""
    return summarize(load(recording))


def format_summary(summary: dict) -> str:
    """Human-readable text of `summarize`'s result (kV, µA, degrees)."""
    lines = [f"duration {summary['duration']:.3f} s"]
    for topic, count in summary["message_counts"].items():
        lines.append(f"  {topic}: {count} messages")
    for name, channel in summary["channels"].items():
        lines.append(f"channel {name}: peak {channel['peak_voltage'] / 1e3:.3f} kV at "
                     f"{channel['peak_voltage_time']:.3f} s, peak current "
                     f"{channel['peak_current'] * 1e6:.2f} µA")
    silence = summary["hv_state_longest_silence"]
    if silence:
        lines.append(f"hv/state: longest silence {silence['seconds']:.3f} s (from {silence['from']:.3f} s)")
    for step in summary["steps"]:
        duration = "-" if step["duration"] is None else f"{step['duration']:.3f} s"
        lines.append(f"step {step['step_index']} {step['step_name']}: {step['outcome']} "
                     f"after {duration} (from {step['start']:.3f} s)")
    for fault in summary["faults"]:
        text = f" ({fault['fault_text']})" if fault["fault_text"] else ""
        lines.append(f"fault {fault['event']} at {fault['time']:.3f} s on {fault['channel']}: "
                     f"{', '.join(fault['faults'])}{text}")
    for name, chain in summary["chains"].items():
        degrees = ", ".join(f"{math.degrees(a):.1f}" for a in chain["final_angles"])
        lines.append(f"chain {name}: final block angles [{degrees}] deg")
    for name, chain in summary["estimated_chains"].items():
        degrees = ", ".join(f"{math.degrees(a):.1f}" for a in chain["final_angles"])
        difference = chain["median_minus_predicted"]
        versus = "" if difference is None else (
            "; estimated - predicted, median: [" + ", ".join(f"{math.degrees(a):+.2f}" for a in difference) + "] deg")
        lines.append(f"chain {name}: estimated from {chain['samples']} images, final [{degrees}] deg{versus}")
    for topic, report in summary["lost_samples"].items():
        spans = ", ".join(f"{g['lost']} between {g['from']:.3f} and {g['to']:.3f} s" for g in report["gaps"])
        lines.append(f"{topic}: {report['lost']} samples lost on the way to the recorder ({spans})")
    return "\n".join(lines)
