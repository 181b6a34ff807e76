"""How long rclpy's publish() can hold a process when a reader stops answering, per Fast DDS publication mode.

Writes docs/figures/publish_hold.png and docs/figures/publish_hold.json.
    scripts/with_env.sh python benchmarks/publish_hold.py [--trials 8]
Each trial: a reliable publisher (depth 10, 2 kB samples at 50 Hz) in a process of its own, its reader in another;
2 s after the start the reader's process is stopped (SIGSTOP) for 3 s, then let go. The publisher times every
publish(). rclpy holds the interpreter lock through publish(), so a long one stands every thread of its process
still (the HV driver's control loop, in the driver's). Each trial runs in a ROS domain of its own.
"""
import argparse
import json
import os
import signal
import subprocess
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "figures")
MODES = ("SYNCHRONOUS", "ASYNCHRONOUS")
RATE_HZ, SAMPLE_BYTES, DEPTH = 50.0, 2000, 10
STOP_AT_S, STOPPED_S, RUN_S = 2.0, 3.0, 8.0
FIRST_DOMAIN = 200  # trials use domains 200.. (Fast DDS allows up to 232)

READER = f"""
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("publish_hold_reader")
node.create_subscription(String, "publish_hold", lambda msg: None,
                         QoSProfile(depth={DEPTH}, reliability=ReliabilityPolicy.RELIABLE))
print("ready", flush=True)
rclpy.spin(node)
"""
PUBLISHER = f"""
import json, os, signal, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
reader = int(sys.argv[1])
rclpy.init()
node = rclpy.create_node("publish_hold_publisher")
publisher = node.create_publisher(String, "publish_hold",
                                  QoSProfile(depth={DEPTH}, reliability=ReliabilityPolicy.RELIABLE))
while publisher.get_subscription_count() < 1:
    time.sleep(0.05)
message, durations, state = String(data="x" * {SAMPLE_BYTES}), [], "running"
began = time.monotonic()
while (elapsed := time.monotonic() - began) < {RUN_S}:
    if state == "running" and elapsed > {STOP_AT_S}:
        os.kill(reader, signal.SIGSTOP); state = "stopped"
    elif state == "stopped" and elapsed > {STOP_AT_S + STOPPED_S}:
        os.kill(reader, signal.SIGCONT); state = "resumed"
    before = time.monotonic()
    publisher.publish(message)
    durations.append([elapsed, time.monotonic() - before])
    time.sleep(1.0 / {RATE_HZ})
print(json.dumps(durations))
"""


def trial(mode: str, domain: int) -> list[list[float]]:
    environment = {**os.environ, "RMW_FASTRTPS_PUBLICATION_MODE": mode, "ROS_DOMAIN_ID": str(domain),
                   "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    reader = subprocess.Popen([sys.executable, "-c", READER], env=environment, stdout=subprocess.PIPE, text=True)
    try:
        assert reader.stdout.readline().strip() == "ready"
        published = subprocess.run([sys.executable, "-c", PUBLISHER, str(reader.pid)], env=environment,
                                   capture_output=True, text=True, timeout=120, check=True)
        return json.loads(published.stdout.strip().splitlines()[-1])
    finally:
        reader.send_signal(signal.SIGCONT)
        reader.kill()
        reader.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=8, help="trials per mode (default 8)")
    trials = parser.parse_args().trials
    os.makedirs(FIGURES, exist_ok=True)
    results = {mode: [] for mode in MODES}
    for k in range(trials):
        for m, mode in enumerate(MODES):
            durations = trial(mode, FIRST_DOMAIN + (k * len(MODES) + m) % 32)
            longest = max(d for _, d in durations)
            held = sum(d for _, d in durations if d > 0.05)
            results[mode].append({"longest_publish_s": longest, "held_s": held, "durations": durations})
            print(f"trial {k + 1}/{trials} {mode:12s}: longest publish {longest * 1e3:7.1f} ms, "
                  f"held {held:.2f} s in all", flush=True)
    summary = {mode: {"trials": trials,
                      "trials_held_over_0.1_s": sum(r["longest_publish_s"] > 0.1 for r in runs),
                      "median_longest_publish_s": float(np.median([r["longest_publish_s"] for r in runs])),
                      "max_longest_publish_s": max(r["longest_publish_s"] for r in runs)}
               for mode, runs in results.items()}
    with open(os.path.join(FIGURES, "publish_hold.json"), "w") as out:
        json.dump({"setup": {"rate_hz": RATE_HZ, "sample_bytes": SAMPLE_BYTES, "depth": DEPTH,
                             "reader_stopped_s": [STOP_AT_S, STOP_AT_S + STOPPED_S]},
                   "summary": summary,
                   "trials": {mode: [{k: v for k, v in r.items() if k != "durations"} for r in runs]
                              for mode, runs in results.items()}}, out, indent=1)
    figure, axes = plt.subplots(1, len(MODES), figsize=(11, 3.8), sharey=True)
    for axis, mode in zip(axes, MODES):
        for r in results[mode]:
            times, durations = np.array(r["durations"]).T
            axis.plot(times, durations * 1e3, lw=0.8)
        axis.axvspan(STOP_AT_S, STOP_AT_S + STOPPED_S, color="0.9", label="reader stopped")
        s = summary[mode]
        axis.set_title(f"{mode}: {s['trials_held_over_0.1_s']} of {trials} trials held > 0.1 s", fontsize=10)
        axis.set_xlabel("time [s]")
        axis.legend(loc="upper right", fontsize=8)
    axes[0].set_ylabel("publish() duration [ms]")
    figure.suptitle("rclpy publish() with a reliable reader whose process stops (Fast DDS, 50 Hz, 2 kB)")
    figure.tight_layout()
    figure.savefig(os.path.join(FIGURES, "publish_hold.png"), dpi=120)
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
