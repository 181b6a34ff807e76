"""ROS node timings: the assembly-state prediction, hv/state -> assembly/state latency, planner overhead.

1. Prediction cost: computing one AssemblyState + MarkerArray (what the assembly-state node does when a
   channel voltage changes) for each assembly in config/assemblies, median of REPEATS.
2. Latency: an in-process assembly-state node (default rate 10 Hz) and a client publishing hv/state with
   a new front-channel voltage at a random phase of the timer; time until an assembly/state carrying that
   voltage arrives (at most one period plus the prediction).
3. Planner overhead: a DesignPath service round trip minus the direct planner.design.design_path call for
   the same 2-block path (serialisation, DDS on loopback, executor hand-over).
Wall-clock medians on the shared 2-core machine. Writes docs/figures/ros_nodes.json and .png.
    scripts/with_env.sh python benchmarks/ros_nodes.py [--quick]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import threading
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from softblock_interfaces.msg import AssemblyState, HvChannelState, HvState  # noqa: E402
from softblock_interfaces.srv import DesignPath  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from planner import design  # noqa: E402
from planner.assembly import load_assembly  # noqa: E402
from planner.kinematics import assembly_centerlines, chain_shape  # noqa: E402
from planner.table import load_table  # noqa: E402
from softblock_config import config_file  # noqa: E402
from softblock_ros.assembly_state_node import AssemblyStateNode  # noqa: E402
from softblock_ros.conversions import chain_state_msg, points_msg  # noqa: E402
from softblock_ros.markers import assembly_markers  # noqa: E402
from softblock_ros.planner_node import PlannerNode  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"


def median_ms(samples) -> float:
    return 1e3 * statistics.median(samples)


def prediction_cost(table, repeats: int) -> dict[str, dict]:
    results = {}
    for path in sorted(config_file("assemblies").glob("*.yaml")):
        assembly = load_assembly(path)
        voltages = {channel: 1000.0 for channel in assembly.hv_channels}
        samples = []
        for _ in range(repeats):
            start = time.perf_counter()
            shapes = assembly_centerlines(assembly, table, voltages)
            [chain_state_msg(c, shapes[c.name], 1000.0) for c in assembly.chains]
            assembly_markers(assembly, shapes, table, Header(frame_id="base"))
            samples.append(time.perf_counter() - start)
        blocks = sum(len(chain.blocks) for chain in assembly.chains)
        results[assembly.name] = {"blocks": blocks, "median_ms": median_ms(samples), "samples_s": samples}
        print(f"  prediction {assembly.name:>16}: {blocks:2d} blocks, median {median_ms(samples):.2f} ms", flush=True)
    return results


def wait_until(predicate, timeout=30.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("no answer within 30 s")
        time.sleep(0.0005)


def state_latency(client, samples: int) -> list[float]:
    hv = client.create_publisher(HvState, "hv/state", 10)
    arrivals: dict[float, float] = {}
    client.create_subscription(AssemblyState, "assembly/state",
                               lambda s: arrivals.setdefault(s.chains[0].voltage, time.perf_counter()), 10)
    wait_until(lambda: hv.get_subscription_count() > 0 and arrivals)
    latencies = []
    rng = np.random.default_rng(0)
    for i in range(samples):
        time.sleep(rng.uniform(0.0, 0.1))  # a random phase against the node's 10 Hz timer
        voltage = 100.0 + i
        sent = time.perf_counter()
        hv.publish(HvState(channels=[HvChannelState(name="front", measured_voltage=voltage)]))
        wait_until(lambda: voltage in arrivals)
        latencies.append(arrivals[voltage] - sent)
        if (i + 1) % 10 == 0:
            print(f"  latency {i + 1}/{samples}: median so far {median_ms(latencies):.1f} ms", flush=True)
    return latencies


def planner_overhead(client, table, samples: int) -> dict:
    shape = chain_shape([table.design(15).theta0, table.design(57).theta0],
                        [table.design(15).rod_length, table.design(57).rod_length], 0.0)
    request = DesignPath.Request(path=points_msg(shape.points), num_blocks=2, allow_rotation=False, method="exact")
    service = client.create_client(DesignPath, "planner/design_path")
    assert service.wait_for_service(timeout_sec=30.0)
    direct, round_trip = [], []
    for i in range(samples):
        start = time.perf_counter()
        design.design_path(shape.points, 2, allow_rotation=False, table=table)
        direct.append(time.perf_counter() - start)
        start = time.perf_counter()
        future = service.call_async(request)
        wait_until(future.done)
        round_trip.append(time.perf_counter() - start)
        assert future.result().success, future.result().message
        print(f"  planner {i + 1}/{samples}: direct {1e3 * direct[-1]:.1f} ms, service {1e3 * round_trip[-1]:.1f} ms",
              flush=True)
    return {"direct_s": direct, "service_s": round_trip, "direct_median_ms": median_ms(direct),
            "service_median_ms": median_ms(round_trip),
            "overhead_median_ms": median_ms(round_trip) - median_ms(direct)}


def plot(results: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    prediction = results["prediction"]
    names = list(prediction)
    axes[0].bar(names, [prediction[n]["median_ms"] for n in names], color="tab:blue")
    axes[0].set_ylabel("median time per update [ms]")
    axes[0].set_title("AssemblyState + markers per voltage change")
    axes[0].tick_params(axis="x", rotation=30)
    latency_ms = 1e3 * np.array(results["latency_s"])
    axes[1].hist(latency_ms, bins=20, color="tab:orange")
    axes[1].axvline(np.median(latency_ms), color="k", linestyle="--", label=f"median {np.median(latency_ms):.0f} ms")
    axes[1].set_xlabel("hv/state -> assembly/state [ms] (node at 10 Hz)")
    axes[1].set_ylabel("samples")
    axes[1].legend()
    planner = results["planner"]
    axes[2].boxplot([1e3 * np.array(planner["direct_s"]), 1e3 * np.array(planner["service_s"])])
    axes[2].set_xticks([1, 2], ["direct call", "DesignPath service"])
    axes[2].set_ylabel("time [ms]")
    axes[2].set_title(f"2-block path design; overhead {planner['overhead_median_ms']:.1f} ms (medians)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples")
    args = parser.parse_args()
    repeats, latency_samples, planner_samples = (20, 20, 5) if args.quick else (200, 60, 20)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    table = load_table()
    print("prediction cost", flush=True)
    results = {"prediction": prediction_cost(table, repeats), "load_average": os.getloadavg()}

    context = rclpy.Context()
    rclpy.init(context=context)
    nodes = [AssemblyStateNode(context=context), PlannerNode(context=context, parameter_overrides=[
        Parameter("default_time_budget_s", value=60.0)]), rclpy.create_node("benchmark_client", context=context)]
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    for node in nodes:
        executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        print("hv/state -> assembly/state latency", flush=True)
        results["latency_s"] = state_latency(nodes[2], latency_samples)
        results["latency_median_ms"] = median_ms(results["latency_s"])
        print("planner service overhead", flush=True)
        results["planner"] = planner_overhead(nodes[2], table, planner_samples)
    finally:
        executor.shutdown(timeout_sec=5.0)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)

    FIGURES.mkdir(parents=True, exist_ok=True)
    (FIGURES / "ros_nodes.json").write_text(json.dumps(results, indent=1))
    plot(results, FIGURES / "ros_nodes.png")
    print(f"latency median {results['latency_median_ms']:.1f} ms; planner overhead median "
          f"{results['planner']['overhead_median_ms']:.1f} ms; wrote {FIGURES / 'ros_nodes.json'} and .png")


if __name__ == "__main__":
    main()
