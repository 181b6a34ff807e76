"""End-to-end demo: the whole stack on the simulated HV supply and the simulated arm.

    python -m softblock_ros.demo --out out/demo          (what `make demo` runs)
    python -m softblock_ros.demo --live-view-port 8766   (the live view elsewhere; 0: a free port, --no-live-view: none)

1. starts hv_driver (sim backend), assembly_state, planner, sim_arm, sim_camera (a side view of the front left
   finger, its blocks slightly off their design), estimator (angles and mistakes from that view), sequencer,
   the MCAP recorder and the live view for Foxglove (foxglove_bridge, ws://127.0.0.1:8765 unless
   --live-view-port or --no-live-view) (config/stack.yaml); the hint to open it is printed once it serves;
2. asks the planner for the paper's gripper fingers for the asymmetric sample object: front fingers of
   4 blocks with the top 2 stiff, back fingers of 5 blocks with the top 3 stiff (Figure 5);
3. loads them into the gripper assembly (assembly/set);
4. runs the six-step finger grasp (sequencer/run, config/sequences/finger_grasp.yaml);
5. injects an over-current fault into a live channel and checks that the outputs go off with a named
   fault, then resets it;
6. stops the stack, analyses the recording (predicted against estimated angles too) and writes plots and a
   summary.
Exit status 0 when every stage did what it should.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import rclpy
import yaml
from action_msgs.msg import GoalStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from softblock_interfaces.action import RampChannel, RunSequence
from softblock_interfaces.msg import HvState
from softblock_interfaces.srv import DesignFingers, InjectFault, SetAssembly
from std_srvs.srv import Trigger

from planner.assembly import load_assembly
from planner.bounded_yaml import load_yaml_file
from planner.contours import OBJECTS_CATALOG
from planner.design import DEFAULT_MIN_STIFF_ROD_DIAMETER
from planner.finger_plot import plot_fingers
from planner.table import load_table
from recording.analysis import load, summarize
from recording.analysis_plot import plot as plot_recording
from softblock_config import config_file

from .client import ActionClient, ClientError, call_service, run_action, status_name, wait_until
from .conversions import assembly_msg, chain_from_msg
from .hv_control import HvControl
from .foxglove_bridge_node import SERVING
from .launcher import OutputWatch, Stack
from .planner_node import READY as PLANNER_READY
from .stack import load_stack

DEMO_ASSEMBLY = "assemblies/gripper.yaml"
FINGER_SETS = {  # paper Figure 5: blocks per finger, top blocks forced stiff
    "front": {"num_blocks": 4, "num_stiff_top": 2},
    "back": {"num_blocks": 5, "num_stiff_top": 3},
}
SERVICE_TIMEOUT = 60.0  # [s] first calls wait for the nodes to start on a loaded machine
# [s] The planner prepares its search at niceness 10 (config/stack.yaml): beside busy loops its start takes
# minutes, and the wait ends at once if it exits, so this bounds a hang only.
PLANNER, PLANNER_START_TIMEOUT = "planner", 600.0
FINGER_TIME_BUDGET = 1.0  # [s] per finger pair: the best design found by then, certified if the search ended
FAULT_CHANNEL, FAULT = "front", "over_current"
LIVE_VIEW = "foxglove_bridge"  # optional in the stack: the demo runs it, to watch in Foxglove
LIVE_VIEW_PORT = 8765  # the bridge's default port (its `port` parameter)
RESET_CURRENT = 1e-6  # [A] the fault drill resets only once the readback shows no arc current


def say(text: str) -> None:
    print(f"[demo] {text}", flush=True)


def write_parameters(out: Path, recording: Path, extra: dict | None = None) -> Path:
    """The demo's additions to the stack's own parameter files (config/stack.yaml): the recorder's output,
    the assembly the fingers are designed for, and ``extra`` (node -> parameter -> value)."""
    parameters = {"recorder": {"ros__parameters": {"output": str(recording)}},
                  "assembly_state": {"ros__parameters": {"assembly_file": DEMO_ASSEMBLY}}}
    for node, values in (extra or {}).items():
        parameters.setdefault(node, {"ros__parameters": {}})["ros__parameters"].update(values)
    path = out / "params.yaml"
    path.write_text(yaml.safe_dump(parameters, sort_keys=False))
    return path


class DemoClient:
    """The demo's ROS side: clients of the stack's services and actions, and the latest hv/state."""

    def __init__(self):
        self.node = rclpy.create_node("demo")
        self.hv_state: HvState | None = None
        self.node.create_subscription(HvState, "hv/state", self._on_hv_state, qos_profile_sensor_data)
        self.design_fingers = self.node.create_client(DesignFingers, "planner/design_fingers")
        self.set_assembly = self.node.create_client(SetAssembly, "assembly/set")
        self.inject_fault = self.node.create_client(InjectFault, "hv/inject_fault")
        self.reset_faults = self.node.create_client(Trigger, "hv/reset_faults")
        self.run_sequence = ActionClient(self.node, RunSequence, "sequencer/run")
        self.ramp = ActionClient(self.node, RampChannel, "hv/ramp")
        # The sequencer holds control of the HV driver during the grasp; the demo claims it for its own
        # fault drill (heartbeats while it holds it).
        self.control = HvControl(self.node, "demo", heartbeat_rate_hz=10.0, timeout_s=SERVICE_TIMEOUT)
        self.executor = SingleThreadedExecutor()  # a client: see softblock_ros.client
        self.executor.add_node(self.node)
        self._spinner = threading.Thread(target=self.executor.spin, daemon=True)
        self._spinner.start()

    def _on_hv_state(self, message: HvState) -> None:
        self.hv_state = message

    def channel(self, name: str):
        state = self.hv_state
        return next((c for c in state.channels if c.name == name), None) if state else None

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=5.0)
        self._spinner.join(timeout=5.0)
        self.node.destroy_node()


def design_gripper(client: DemoClient, object_name: str) -> tuple[dict, dict]:
    """Front and back finger designs from the planner node; returns (finger set -> side -> (chain, objective),
    summary)."""
    catalog = load_yaml_file(OBJECTS_CATALOG)[object_name]
    fingers, summary = {}, {}
    for finger_set, constraints in FINGER_SETS.items():
        request = DesignFingers.Request(
            image_path=str(OBJECTS_CATALOG.parent / catalog["file"]), pixel_size=float(catalog["pixel_size_m"]),
            min_stiff_rod_diameter=DEFAULT_MIN_STIFF_ROD_DIAMETER, method="exact", time_budget=FINGER_TIME_BUDGET,
            **constraints)
        response = call_service(client.design_fingers, request, timeout=SERVICE_TIMEOUT + 60.0)
        if not response.success:
            raise ClientError(f"planner could not design the {finger_set} fingers: {response.message}")
        fingers[finger_set] = {side: (chain_from_msg(getattr(response, side)), getattr(response, f"{side}_cost"))
                               for side in ("left", "right")}
        summary[finger_set] = {
            side: {"design_ids": [b.design.id for b in getattr(response, side).blocks],
                   "cost_m": getattr(response, f"{side}_cost"), "collision": getattr(response, f"{side}_collision")}
            for side in ("left", "right")} | {"optimal": response.optimal, "solve_time_s": response.solve_time}
        say(f"{finger_set} fingers ({constraints['num_blocks']} blocks, top {constraints['num_stiff_top']} stiff): "
            f"left {summary[finger_set]['left']['design_ids']}, right {summary[finger_set]['right']['design_ids']}, "
            f"objective {response.left_cost:.3f} / {response.right_cost:.3f} m, "
            f"{'certified optimal' if response.optimal else 'not certified'}, {response.solve_time:.2f} s")
    return fingers, summary


def load_designs_into_gripper(client: DemoClient, fingers: dict, name: str | None = None):
    """Replace the gripper's finger blocks with the designs (the chains keep their gripper base poses) and
    set it on assembly_state, named ``name`` (default: the gripper file's); returns the assembly."""
    gripper = load_assembly(config_file(DEMO_ASSEMBLY))
    designed = gripper.with_chains(*(replace(chain, blocks=fingers[finger_set][side][0].blocks)
                                     for chain in gripper.chains for finger_set, side in [chain.name.split("_")]))
    designed = replace(designed, name=name or designed.name)
    set_assembly(client, designed)
    say(f"designed fingers loaded into the gripper assembly {designed.name!r}")
    return designed


def set_assembly(client: DemoClient, assembly) -> None:
    """assembly/set: what the stack believes is built."""
    response = call_service(client.set_assembly, SetAssembly.Request(assembly=assembly_msg(assembly, load_table())),
                            timeout=SERVICE_TIMEOUT)
    if not response.success:
        raise ClientError(f"assembly/set refused {assembly.name!r}: {response.message}")


def run_grasp(client: DemoClient) -> dict:
    def feedback(message):
        f = message.feedback
        if f.phase == "running":
            say(f"  step {f.step_index + 1}/{f.step_count} {f.step_name}: {f.description}")

    say("running the six-step finger grasp (sequencer/run finger_grasp)")
    status, result = run_action(client.run_sequence, RunSequence.Goal(sequence="finger_grasp"), timeout=300.0,
                                feedback=feedback, server_timeout=SERVICE_TIMEOUT)
    say(f"grasp {status_name(status)}: {result.message}")
    return {"status": status_name(status), "success": status == GoalStatus.STATUS_SUCCEEDED and result.success,
            "message": result.message, "failed_step": result.failed_step,
            "steps": dict(zip(result.step_names, result.step_durations))}


def fault_drill(client: DemoClient) -> dict:
    """The fault drill with the demo holding control of the HV driver (claimed, then released)."""
    client.control.claim()
    try:
        return inject_fault_mid_ramp(client)
    finally:
        say(f"  HV control: {client.control.release()}")


def inject_fault_mid_ramp(client: DemoClient) -> dict:
    """Ramp a channel, inject an over-current (film breakdown) into the simulated supply mid-ramp,
    and time how long the driver takes to switch the output off with a named fault."""
    say(f"fault drill: ramping {FAULT_CHANNEL} toward 1.2 kV, then injecting {FAULT}")
    outcome = {}
    ramp = threading.Thread(target=lambda: outcome.setdefault("ramp", run_action(
        client.ramp, client.control.ramp_goal(FAULT_CHANNEL, 1200.0), timeout=60.0,
        server_timeout=SERVICE_TIMEOUT)), daemon=True)
    ramp.start()
    wait_until(lambda: (c := client.channel(FAULT_CHANNEL)) and c.measured_voltage > 600.0, 30.0,
               f"{FAULT_CHANNEL} above 600 V")
    injected = time.monotonic()
    reply = call_service(client.inject_fault, InjectFault.Request(channel=FAULT_CHANNEL, fault=FAULT), SERVICE_TIMEOUT)
    if not reply.success:
        raise ClientError(f"hv/inject_fault refused: {reply.message}")
    channel = wait_until(lambda: (c := client.channel(FAULT_CHANNEL)) and c.faults and not c.output_enabled and c,
                         5.0, f"{FAULT_CHANNEL} to switch off with a fault")
    seen_off = time.monotonic() - injected
    ramp.join(timeout=30.0)
    ramp_status = status_name(outcome["ramp"][0]) if "ramp" in outcome else "no result"
    say(f"  {FAULT_CHANNEL}: output off, fault '{channel.fault_text}' seen on hv/state {1e3 * seen_off:.0f} ms "
        f"after injection; the ramp action ended {ramp_status}")
    # Remove the cause (in the lab: replace the broken block), then reset on purpose.
    cleared = call_service(client.inject_fault, InjectFault.Request(channel=FAULT_CHANNEL, fault="clear"),
                           SERVICE_TIMEOUT)
    if not cleared.success:
        raise ClientError(f"hv/inject_fault could not clear the fault: {cleared.message}")
    # A reset while the arc current still shows in the readback would trip again at once.
    wait_until(lambda: (c := client.channel(FAULT_CHANNEL)) and abs(c.measured_current) < RESET_CURRENT, 10.0,
               f"the {FAULT_CHANNEL} current to decay below {RESET_CURRENT * 1e6:g} µA")
    reset = call_service(client.reset_faults, Trigger.Request(), SERVICE_TIMEOUT)
    if not reset.success:
        raise ClientError(f"hv/reset_faults refused: {reset.message}")
    wait_until(lambda: (c := client.channel(FAULT_CHANNEL)) and not c.faults, 10.0, "the fault to clear")
    say(f"  faults reset ({reset.message})")
    return {"channel": FAULT_CHANNEL, "fault": FAULT, "fault_text": channel.fault_text,
            "output_enabled_after": channel.output_enabled, "seen_off_after_s": seen_off,
            "ramp_result": ramp_status}


def analyse(recording: Path, out: Path, title: str = "finger grasp on the simulated stack") -> dict:
    data = load(str(recording))
    summary = summarize(data)
    plot_recording(data, str(out / "recording.png"), title=title)
    say(f"recording analysed: {out / 'recording.png'}")
    return summary


def live_view_url(stack: Stack, serving: OutputWatch, timeout: float = SERVICE_TIMEOUT) -> str | None:
    """The address the live view serves on once its node says it listens; None if the node ended first (a port
    that is taken) or said nothing within ``timeout``."""
    found = re.search(r"ws://\S+", stack.wait_for(serving, timeout) or "")
    return found.group(0) if found else None


def wait_for_planner(stack: Stack, ready: OutputWatch) -> None:
    """Return once the planner node says it is ready; ClientError if it exits first or takes longer than
    PLANNER_START_TIMEOUT."""
    if ready.line is None:
        say("waiting for the planner to prepare its finger search (niced batch work: slow on a busy machine)")
    if stack.wait_for(ready, PLANNER_START_TIMEOUT) is None:
        ended = stack.dead().get(PLANNER)
        raise ClientError(f"the planner ended with code {ended} before it was ready" if ended is not None else
                          f"the planner was not ready within {PLANNER_START_TIMEOUT:g} s")


def announce_live_view(stack: Stack, serving: OutputWatch, report: dict) -> None:
    url = report["live_view"] = live_view_url(stack, serving)
    if url:
        say(f"live view: open {url} in Foxglove with config/foxglove/softblock_layout.json")
    else:
        ended = stack.dead().get(LIVE_VIEW)
        why = f"foxglove_bridge ended with code {ended}" if ended is not None else "no word from foxglove_bridge"
        say(f"live view: not serving ({why}; see stack.log); the demo goes on without it")


def run_stack(out: Path, params: Path, scenario, report: dict, nodes=(LIVE_VIEW,), client_class=None) -> None:
    """Start the stack (its default nodes and ``nodes``) with the parameter files ``params``, wait for hv/state,
    run ``scenario(client)`` with a ``client_class`` (default DemoClient) and stop the stack. A ClientError is
    recorded as ``report["error"]``; the nodes' exit codes go to ``report["exit_codes"]``, the live view's
    address (when ``nodes`` has it) to ``report["live_view"]`` (None: not serving)."""
    with open(out / "stack.log", "w") as log:
        say(f"starting the stack on the simulated backend (node output: {out / 'stack.log'})")
        stack = Stack(nodes=[*load_stack().default_names, *nodes], params=params, output=log)
        serving = stack.watch(LIVE_VIEW, SERVING)
        planner_ready = stack.watch(PLANNER, PLANNER_READY)
        stack.start()
        os.environ.update(stack.network.variables(os.environ))  # the demo's client joins the nodes' network
        rclpy.init()
        client = (client_class or DemoClient)()
        try:
            wait_until(lambda: (s := client.hv_state) and len(s.channels) == 2, SERVICE_TIMEOUT, "hv/state")
            if LIVE_VIEW in nodes:
                announce_live_view(stack, serving, report)
            if PLANNER in stack.nodes:
                wait_for_planner(stack, planner_ready)
            scenario(client)
        except ClientError as error:
            say(f"FAILED: {error}")
            report["error"] = str(error)
        finally:
            client.close()
            rclpy.try_shutdown()
            say("stopping the stack")
            report["exit_codes"] = stack.stop()


def run(out: Path, object_name: str, live_view_port: int | None = LIVE_VIEW_PORT) -> int:
    """The demo; ``live_view_port`` None runs it without the live view (0: on a free port)."""
    out.mkdir(parents=True, exist_ok=True)
    recording = out / "run.mcap"
    recording.unlink(missing_ok=True)
    live_view = {} if live_view_port is None else {LIVE_VIEW: {"port": live_view_port}}
    params = write_parameters(out, recording, live_view)
    started = time.monotonic()
    report: dict = {"object": object_name}

    def scenario(client: DemoClient) -> None:
        fingers, report["designs"] = design_gripper(client, object_name)
        plot_fingers(fingers, object_name, out / "fingers.png")
        say(f"finger designs drawn over the object: {out / 'fingers.png'}")
        load_designs_into_gripper(client, fingers)
        report["grasp"] = run_grasp(client)
        report["fault_drill"] = fault_drill(client)

    run_stack(out, params, scenario, report, nodes=tuple(live_view))
    report["recording"] = analyse(recording, out)
    report["duration_s"] = time.monotonic() - started
    (out / "summary.json").write_text(json.dumps(report, indent=2, default=float))
    print_summary(report, out)
    ok = "error" not in report and report["grasp"]["success"] and not report["fault_drill"]["output_enabled_after"]
    return 0 if ok else 1


def print_summary(report: dict, out: Path) -> None:
    print("\n=== demo summary ===")
    for finger_set, design in report.get("designs", {}).items():
        for side in ("left", "right"):
            d = design[side]
            print(f"{finger_set:>5} {side:<5} IDs {d['design_ids']}  objective {d['cost_m']:.3f} m"
                  f"{'  COLLISION' if d['collision'] else ''}")
    grasp = report.get("grasp")
    if grasp:
        print(f"grasp: {grasp['status']}")
        for step, duration in grasp["steps"].items():
            print(f"  {step:<20} {duration:6.2f} s")
    for name, channel in report["recording"]["channels"].items():
        print(f"channel {name}: peak {channel['peak_voltage'] / 1e3:.3f} kV")
    silence = report["recording"]["hv_state_longest_silence"]
    if silence:  # to compare with the sequencer's state_timeout_s, after which it counts the driver as lost
        print(f"hv/state: longest silence {1e3 * silence['seconds']:.0f} ms (from {silence['from']:.1f} s)")
    drill = report.get("fault_drill")
    if drill:
        print(f"fault drill: {drill['fault']} on {drill['channel']} -> '{drill['fault_text']}', output off "
              f"{1e3 * drill['seen_off_after_s']:.0f} ms after injection (as seen on hv/state)")
    for name, chain in report["recording"]["estimated_chains"].items():
        difference = chain["median_minus_predicted"]
        versus = "" if difference is None else ", estimated - predicted (median) [" + ", ".join(
            f"{math.degrees(a):+.2f}" for a in difference) + "] deg"
        print(f"chain {name} seen by the camera: {chain['samples']} estimates{versus}")
    faults = report["recording"]["faults"]
    print(f"fault events in the recording: {len(faults)}")
    print(f"recording: {out / 'run.mcap'} ({sum(report['recording']['message_counts'].values())} messages)")
    print(f"plots: {out / 'fingers.png'}, {out / 'recording.png'}; summary: {out / 'summary.json'}")
    print(f"total {report['duration_s']:.1f} s")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    parser.add_argument("--object", default="asymmetric", help="sample object (config/objects/objects.yaml)")
    view = parser.add_mutually_exclusive_group()
    view.add_argument("--live-view-port", type=int, default=LIVE_VIEW_PORT, metavar="PORT",
                      help=f"port of the live view for Foxglove (default {LIVE_VIEW_PORT}; 0: a free port, printed)")
    view.add_argument("--no-live-view", action="store_true", help="run without the live view (foxglove_bridge)")
    args = parser.parse_args(argv)
    if not 0 <= args.live_view_port <= 65535:
        parser.error(f"--live-view-port {args.live_view_port}: a port is 0..65535")
    return run(args.out.resolve(), args.object, None if args.no_live_view else args.live_view_port)


if __name__ == "__main__":
    sys.exit(main())
