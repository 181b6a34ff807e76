"""Recorder under load: HvState published at 1 kHz for DURATION s, published vs recorded counts.

Runs the recorder CLI as its own process (all-topics mode, default settings) and a publisher in
this process, stops it with SIGINT and reads the file back; then a second run is killed with
SIGKILL while publishing and recovered, to measure what a crash loses.
Writes docs/figures/recorder_load.json and .png.

    scripts/with_env.sh python benchmarks/recorder_load.py [--duration 60] [--rate 1000]
"""
import argparse
import json
import os
import random
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import rclpy  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402
from softblock_interfaces.msg import HvChannelState, HvState  # noqa: E402

from recording.mcap_file import recover  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "figures")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (from /proc)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def publish_at_rate(node, publisher, rate: float, duration: float) -> int:
    """Publishes on an absolute schedule (late ticks are caught up); returns how many were sent."""
    period, sent, start = 1.0 / rate, 0, time.monotonic()
    channels = [HvChannelState(name=name, index=i, ceiling=4000.0, output_enabled=True)
                for i, name in enumerate(("front", "back"))]
    next_report = 5.0
    while (elapsed := time.monotonic() - start) < duration:
        if sent * period > elapsed:
            time.sleep(sent * period - elapsed)
        message = HvState(device_id="bench", backend="sim", channels=channels)
        message.channels[0].measured_voltage = float(sent)  # sequence number, to find gaps
        message.header.stamp = node.get_clock().now().to_msg()
        publisher.publish(message)
        sent += 1
        if elapsed >= next_report:
            print(f"  {elapsed:5.1f} s / {duration:.0f} s: {sent} published", flush=True)
            next_report += 5.0
    return sent


def run_recorder(node, publisher, path: str, rate: float, duration: float, stop_signal):
    """Recorder process on `path` while publishing; returns (published, recorder CPU %, log)."""
    recorder = subprocess.Popen([sys.executable, "-m", "softblock_ros.recording", "record",
                                 "-o", path], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    if publisher.get_subscription_count() < 1:
        recorder.kill()
        raise SystemExit("the recorder did not subscribe to /hv/state within 60 s")
    cpu_before, wall_before = cpu_seconds(recorder.pid), time.monotonic()
    published = publish_at_rate(node, publisher, rate, duration)
    if stop_signal != signal.SIGKILL:
        time.sleep(1.0)  # let the last messages arrive
    cpu_percent = 100.0 * (cpu_seconds(recorder.pid) - cpu_before) / (time.monotonic()
                                                                      - wall_before)
    recorder.send_signal(stop_signal)
    _, recorder_log = recorder.communicate(timeout=60)
    while stop_signal != signal.SIGKILL and publisher.get_subscription_count() > 0:
        time.sleep(0.05)  # the next run must match its own recorder, not this one
    return published, cpu_percent, recorder_log


def read_back(path: str, topic: str):
    """Sequence numbers, log times and publish times of `topic` in the file."""
    sequence, log_times, publish_times = [], [], []
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _, _, message, decoded in reader.iter_decoded_messages(topics=[topic]):
            sequence.append(int(decoded.channels[0].measured_voltage))
            log_times.append(message.log_time)
            publish_times.append(message.publish_time)
    return sequence, log_times, publish_times, summary.statistics.chunk_count


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load")
    parser.add_argument("--rate", type=float, default=1000.0, help="messages per second")
    parser.add_argument("--kill-after", type=float, default=10.0,
                        help="seconds of load before the SIGKILL run kills the recorder")
    parser.add_argument("--out-dir", default=FIGURES)
    args = parser.parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(random.randint(101, 199))  # no cross-talk with tests
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    workdir = tempfile.mkdtemp(prefix="recorder_load_")
    path = os.path.join(workdir, "load.mcap")

    rclpy.init()
    node = rclpy.create_node("hv_driver")
    publisher = node.create_publisher(HvState, "hv/state", 1000)
    print(f"publishing {args.rate:.0f} Hz for {args.duration:.0f} s, then SIGINT", flush=True)
    published, cpu_percent, recorder_log = run_recorder(node, publisher, path, args.rate,
                                                        args.duration, signal.SIGINT)
    print(f"publishing {args.rate:.0f} Hz for {args.kill_after:.0f} s, then SIGKILL", flush=True)
    killed_path = os.path.join(workdir, "killed.mcap")
    killed_published, _, _ = run_recorder(node, publisher, killed_path, args.rate,
                                          args.kill_after, signal.SIGKILL)
    recovered = recover(killed_path, os.path.join(workdir, "recovered.mcap"))
    node.destroy_node()
    rclpy.try_shutdown()

    sequence, log_times, publish_times, chunks = read_back(path, "/hv/state")
    file_bytes = os.path.getsize(path)
    shutil.rmtree(workdir)
    latencies_ms = [(log - pub) / 1e6 for log, pub in zip(log_times, publish_times)]
    seconds = [(t - log_times[0]) / 1e9 for t in log_times] if log_times else []
    per_second = [0] * (int(max(seconds, default=0)) + 1)
    for t in seconds:
        per_second[int(t)] += 1
    result = {
        "command": "scripts/with_env.sh python benchmarks/recorder_load.py "
                   f"--duration {args.duration:g} --rate {args.rate:g}",
        "duration_s": args.duration, "target_rate_hz": args.rate,
        "published": published, "recorded": len(sequence),
        "lost": published - len(set(sequence)),
        "in_order": sequence == sorted(sequence),
        "achieved_publish_rate_hz": published / args.duration,
        "median_recorded_per_second": statistics.median(per_second[1:-1] or per_second),
        "latency_ms": {"median": statistics.median(latencies_ms),
                       "p99": sorted(latencies_ms)[int(0.99 * (len(latencies_ms) - 1))],
                       "max": max(latencies_ms)} if latencies_ms else {},
        "recorder_cpu_percent": cpu_percent,
        "sigkill": {"published": killed_published, "recovered": recovered.messages,
                    "lost": killed_published - recovered.messages,
                    "lost_s": (killed_published - recovered.messages) / args.rate},
        "file_bytes": file_bytes, "chunks": chunks,
        "bytes_per_message": file_bytes / max(len(sequence), 1),
        "settings": "zstd, 256 KiB chunks, flush every 1 s, all-topics mode",
    }
    os.makedirs(args.out_dir, exist_ok=True)
    with open(os.path.join(args.out_dir, "recorder_load.json"), "w", encoding="utf-8") as out:
        json.dump(result, out, indent=2)
    plot(result, per_second, latencies_ms, os.path.join(args.out_dir, "recorder_load.png"))
    print(json.dumps(result, indent=2))
    print(recorder_log.strip().splitlines()[-1] if recorder_log.strip() else "")
    return 0 if result["lost"] == 0 else 1


def plot(result: dict, per_second: list, latencies_ms: list, png_path: str) -> None:
    figure, (rate_axis, latency_axis) = plt.subplots(1, 2, figsize=(11, 4))
    rate_axis.axhline(result["target_rate_hz"], color="tab:gray", linestyle="--",
                      label=f"published ({result['published']} in total)")
    rate_axis.plot(range(len(per_second)), per_second, marker=".",
                   label=f"recorded ({result['recorded']}, lost {result['lost']})")
    rate_axis.set_xlabel("time [s]")
    rate_axis.set_ylabel("messages per second")
    rate_axis.set_ylim(0, result["target_rate_hz"] * 1.2)
    rate_axis.legend(loc="lower right")
    killed = result["sigkill"]
    rate_axis.text(0.02, 0.04, f"SIGKILL run: {killed['lost']} of {killed['published']} lost "
                   f"({1e3 * killed['lost_s']:.0f} ms of data), rest recovered",
                   transform=rate_axis.transAxes, fontsize=8)
    rate_axis.set_title("HvState at 1 kHz: recorded per second")
    latency_axis.hist(latencies_ms, bins=100, log=True)
    latency_axis.axvline(result["latency_ms"]["median"], color="tab:red",
                         label=f"median {result['latency_ms']['median']:.3f} ms")
    latency_axis.set_xlabel("receipt - source timestamp [ms]")
    latency_axis.set_ylabel("messages")
    latency_axis.legend()
    latency_axis.set_title("delivery latency into the recorder")
    for axis in (rate_axis, latency_axis):
        axis.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(png_path, dpi=110)
    plt.close(figure)


if __name__ == "__main__":
    sys.exit(main())
