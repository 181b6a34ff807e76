"""Second demo: the strawberry gripper becomes the asymmetric-object gripper in a few block swaps.

    python -m softblock_ros.demo_reconfigure --out out/reconfigure      (what `make demo-reconfigure` runs)

1. starts the stack of config/stack.yaml on the simulated backend (as `make demo`, without the live view);
2. designs the paper's gripper (Figure 5) for the strawberry (planner/design_fingers) and sets it as built;
3. plans the change of the front finger pair to the asymmetric object (planner/plan_reconfiguration): the
   Pareto set of swaps against the objective from a shelf of SHELF_COUNT blocks of every design, and the
   operator steps of the point with at most ``--swaps`` swaps;
4. writes the plan as a sequence: an ``operator_swap`` step, then the new front fingers closed at 2.4 kV and
   opened again;
5. runs it with one swap done wrong: the simulated operator puts a look-alike block (rods of the same length
   but another diameter, the same film) at one of the watched finger's swapped positions. The simulated camera draws what was built
   (sim/assembly_built), the estimator finds the wrong block and the sequence ends at the swap step naming it,
   with every channel still at 0 V;
6. runs the correction (one swap) the same way, done right: the camera finds the assembly as built and only then
   are the front fingers energised;
7. stops the stack, analyses the recording and writes out/reconfigure/: pareto.png, recording.png, the two
   sequence files, run.mcap, summary.json, stack.log.
Exit status 0 when the wrong swap was caught before any channel was energised and the corrected gripper closed.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402
from action_msgs.msg import GoalStatus  # noqa: E402
from softblock_interfaces.action import PlanReconfiguration, RunSequence  # noqa: E402
from softblock_interfaces.msg import Assembly as AssemblyMsg  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from softblock_interfaces.msg import HvState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from planner.assembly import PlacedBlock  # noqa: E402
from planner.bounded_yaml import load_yaml_file  # noqa: E402
from planner.contours import OBJECTS_CATALOG  # noqa: E402
from planner.table import load_table  # noqa: E402
from sequencing.reconfiguration import operator_swap_step  # noqa: E402
from sequencing.schema import Swap  # noqa: E402

from .client import ActionClient, ClientError, call_service, run_action, status_name, wait_until  # noqa: E402
from .conversions import assembly_from_msg, assembly_msg  # noqa: E402
from .demo import (DemoClient, SERVICE_TIMEOUT, analyse, design_gripper, load_designs_into_gripper,  # noqa: E402
                   run_stack, say, set_assembly, write_parameters)
from .estimator_node import IMAGE_QOS  # noqa: E402
from .qos import LATCHED  # noqa: E402
from .sim_camera_node import WORLD_TOPIC  # noqa: E402

BUILT_FOR, TARGET_OBJECT = "strawberry", "asymmetric"
TARGET_NAME = "asymmetric_gripper"
FRONT_PAIR = (("front_left", "left", 2), ("front_right", "right", 2))  # chain, side, forced-stiff top blocks
WATCHED_CHAIN = "front_left"  # the chain the camera sees (config/camera.yaml)
SHELF_COUNT = 2  # blocks of every design on the shelf
CLOSE_VOLTAGE = 2400.0  # [V] the new front fingers closed once verified
DE_ENERGISED = 50.0  # [V] below this a channel counts as never energised during a swap
SWAP_TIMEOUT = 120.0  # [s] the operator_swap step's own timeout
SEPARABLE_RAD = math.radians(8.0)  # the wrong block's angle differs this much at least


class ReconfigureClient(DemoClient):
    """The demo client, plus the planner's reconfiguration action, the operator's confirmation, the simulated
    world's assembly and the highest voltage measured on hv/state since the last ``reset_peak``."""

    def __init__(self):
        self.peak_voltage = 0.0
        self.image: Image | None = None  # the camera's latest
        super().__init__()
        self.plan = ActionClient(self.node, PlanReconfiguration, "planner/plan_reconfiguration")
        self.operator_done = self.node.create_client(Trigger, "sequencer/operator_done")
        self.world = self.node.create_publisher(AssemblyMsg, WORLD_TOPIC, LATCHED)
        self.node.create_subscription(Image, "camera/silhouette", self._on_image, IMAGE_QOS)

    def _on_image(self, message: Image) -> None:
        self.image = message

    def build(self, assembly, changes_view: bool = True) -> None:
        """The simulated world now holds ``assembly``; with ``changes_view`` (a swap changed the watched chain),
        returns once the camera shows a changed view, so an image taken later shows the new build."""
        before = self.image
        self.world.publish(assembly_msg(assembly, load_table()))
        if changes_view:
                wait_until(lambda: (image := self.image) is not None and (before is None or image.data != before.data),
                       SERVICE_TIMEOUT, "the camera to show the new build")

    def _on_hv_state(self, message: HvState) -> None:
        super()._on_hv_state(message)
        self.peak_voltage = max([self.peak_voltage, *(abs(c.measured_voltage) for c in message.channels)])

    def reset_peak(self) -> None:
        self.peak_voltage = 0.0


def shelf() -> dict[int, int]:
    return {design_id: SHELF_COUNT for design_id in load_table().ids.tolist()}


def plan_front_pair(client: ReconfigureClient, built, max_swaps: int, time_budget: float) -> dict:
    """The planner's plan from the robot as built to the target object; a dict of the Pareto points, the chosen
    point's target assembly and its swaps. The goal names the robot: the planner's own copy of assembly/current may
    not have arrived yet, or may still be the one from before the designs were loaded."""
    catalog = load_yaml_file(OBJECTS_CATALOG)[TARGET_OBJECT]
    stock = shelf()
    goal = PlanReconfiguration.Goal(
        shelf_ids=list(stock), shelf_counts=list(stock.values()),
        object_image_paths=[str(OBJECTS_CATALOG.parent / catalog["file"])],
        pixel_sizes=[float(catalog["pixel_size_m"])], finger_chains=[c for c, _, _ in FRONT_PAIR],
        finger_sides=[s for _, s, _ in FRONT_PAIR], finger_stiff_top=[n for _, _, n in FRONT_PAIR],
        time_budget=time_budget, max_swaps=max_swaps, robot=assembly_msg(built, load_table()))
    say(f"planning the front pair for the {TARGET_OBJECT} object from the robot as built, shelf of {SHELF_COUNT} "
        f"blocks of every design, at most {max_swaps} swaps, {time_budget:g} s budget "
        "(planner/plan_reconfiguration)")
    status, result = run_action(client.plan, goal, timeout=time_budget + 120.0, server_timeout=SERVICE_TIMEOUT)
    if status != GoalStatus.STATUS_SUCCEEDED or not result.success:
        raise ClientError(f"plan_reconfiguration {status_name(status)}: {result.message}")
    points = [{"max_swaps": int(b), "swaps": int(s), "objective_m": float(o), "lower_bound_m": float(lb),
               "certified": bool(c)} for b, s, o, lb, c in zip(result.max_swaps, result.swaps, result.objectives,
                                                               result.lower_bounds, result.optimal)]
    swaps = [Swap(chain, int(position), None if remove < 0 else int(remove), None if insert < 0 else int(insert),
                  int(rotation)) for chain, position, remove, insert, rotation in zip(
                      result.step_chains, result.step_positions, result.step_remove, result.step_insert,
                      result.step_rotation_steps)]
    target, _ = assembly_from_msg(result.target, load_table())
    say(f"  {result.message} ({result.solve_time:.2f} s)")
    for point in points:
        say(f"  <= {point['max_swaps']} swaps: {point['objective_m']:.3f} m (bound {point['lower_bound_m']:.3f} m"
            f"{', certified' if point['certified'] else ''})")
    for text in result.steps:
        say(f"  step: {text}")
    return {"points": points, "target": replace(target, name=TARGET_NAME), "swaps": swaps,
            "solve_time_s": result.solve_time, "message": result.message}


def look_alike(swap: Swap, stock: dict[int, int]) -> int:
    """The block an operator may take for the one ``swap`` inserts: on the shelf, with rods of the same length
    and a film of the same prestretch, but rods of another diameter (tenths of a millimetre apart, hard to tell
    by eye); of those, the nearest in angle to the planned block that still differs by SEPARABLE_RAD (a bigger
    mistake can bend the finger out of the camera's view, a smaller one the camera may not tell)."""
    table = load_table()
    index = {int(i): k for k, i in enumerate(table.ids.tolist())}
    planned = index[swap.insert]

    def looks_alike(design_id: int) -> bool:
        k = index[design_id]
        return (table.rod_length[k] == table.rod_length[planned]
                and table.prestretch_axial[k] == table.prestretch_axial[planned]
                and table.rod_diameter[k] != table.rod_diameter[planned])

    def difference(design_id: int) -> float:
        return abs(table.theta0[index[design_id]] - table.theta0[planned])

    candidates = sorted((d for d, n in stock.items() if n > 0 and d != swap.remove and looks_alike(d)),
                        key=difference)
    if not candidates:
        raise ClientError(f"no look-alike of design {swap.insert} on the shelf")
    return next((d for d in candidates if difference(d) >= SEPARABLE_RAD), candidates[-1])


def with_block(assembly, chain_name: str, position: int, design_id: int):
    chain = assembly.chain(chain_name)
    blocks = list(chain.blocks)
    blocks[position] = replace(blocks[position], design_id=design_id)
    return assembly.with_chains(*(replace(c, blocks=tuple(blocks)) if c.name == chain_name else c
                                  for c in assembly.chains))


def write_sequence(directory: Path, name: str, swaps, description: str) -> Path:
    """An operator_swap step building TARGET_NAME, then the front fingers closed and opened."""
    sequence = {"name": name, "description": description, "channels": ["front", "back"],
                "defaults": {"slew_rate": 1000.0, "tolerance": 50.0, "timeout": 30.0},
                "steps": [operator_swap_step("swap", TARGET_NAME, swaps, timeout_s=SWAP_TIMEOUT),
                          {"name": "close_front", "description": "energise the new front fingers",
                           "ramp": {"channel": "front", "target": CLOSE_VOLTAGE}},
                          {"name": "open_front", "ramp": {"channel": "front", "target": 0.0}}]}
    path = directory / f"{name}.yaml"
    path.write_text(yaml.safe_dump(sequence, sort_keys=False))
    return path


def run_with_operator(client: ReconfigureClient, sequence: str, built, believed) -> dict:
    """Run ``sequence``; when its swap step waits, the simulated operator builds ``built`` (what the camera will
    see), sets ``believed`` on assembly_state (what the operator thinks was built) and confirms."""
    asked = threading.Event()

    def feedback(message):
        f = message.feedback
        if f.phase == "running":
            say(f"  step {f.step_index + 1}/{f.step_count} {f.step_name}: {f.description}")
        elif f.phase == "awaiting_operator":
            asked.set()

    def operator():
        if not asked.wait(SERVICE_TIMEOUT):
            return
        client.build(built)
        set_assembly(client, believed)
        reply = call_service(client.operator_done, Trigger.Request(), SERVICE_TIMEOUT)
        say(f"  operator: {reply.message}")

    client.reset_peak()
    hands = threading.Thread(target=operator, daemon=True)
    hands.start()
    status, result = run_action(client.run_sequence, RunSequence.Goal(sequence=sequence), timeout=300.0,
                                feedback=feedback, server_timeout=SERVICE_TIMEOUT)
    hands.join(timeout=SERVICE_TIMEOUT)
    swap_ended = dict(zip(result.step_names, result.step_durations)).get("swap")
    say(f"  {sequence} {status_name(status)}: {result.message}")
    return {"status": status_name(status), "success": status == GoalStatus.STATUS_SUCCEEDED and result.success,
            "message": result.message, "failed_step": result.failed_step, "swap_step_s": swap_ended,
            "peak_voltage_v": client.peak_voltage}


def plot_pareto(points: list[dict], chosen: int, path: Path) -> None:
    budgets = np.array([p["max_swaps"] for p in points])
    objective = np.array([p["objective_m"] for p in points])
    bound = np.array([p["lower_bound_m"] for p in points])
    fig, axis = plt.subplots(figsize=(6, 4))
    found = np.isfinite(objective)
    axis.step(budgets[found], objective[found], where="post", marker="o", label="best gripper found")
    axis.step(budgets, bound, where="post", ls="--", color="k", lw=1, label="proven lower bound")
    certified = found & np.array([p["certified"] for p in points])
    axis.plot(budgets[certified], objective[certified], "s", color="C2", label="certified")
    if np.isfinite(objective[chosen]):
        axis.plot([budgets[chosen]], [objective[chosen]], "*", ms=14, color="C3", label=f"chosen: <= {chosen} swaps")
    axis.set(xlabel="block swaps (budget)", ylabel="objective, eq. 3 [m]",
             title=f"front pair, {BUILT_FOR} gripper -> {TARGET_OBJECT} object")
    axis.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(out: Path, max_swaps: int, time_budget: float) -> int:
    out.mkdir(parents=True, exist_ok=True)
    sequences = out / "sequences"
    sequences.mkdir(exist_ok=True)
    recording = out / "run.mcap"
    recording.unlink(missing_ok=True)
    params = write_parameters(out, recording, {"sequencer": {"sequences_dir": str(sequences)}})
    started = time.monotonic()
    report: dict = {"built_for": BUILT_FOR, "target_object": TARGET_OBJECT, "max_swaps": max_swaps}

    def scenario(client: ReconfigureClient) -> None:
        fingers, report["designs"] = design_gripper(client, BUILT_FOR)
        built = load_designs_into_gripper(client, fingers, name=f"{BUILT_FOR}_gripper")
        client.build(built, changes_view=False)  # the world holds what was built (as believed)
        plan = plan_front_pair(client, built, max_swaps, time_budget)
        report["plan"] = {k: plan[k] for k in ("points", "solve_time_s", "message")}
        report["plan"]["swaps"] = [swap.describe() for swap in plan["swaps"]]
        plot_pareto(plan["points"], max_swaps, out / "pareto.png")
        watched = [s for s in plan["swaps"] if s.chain == WATCHED_CHAIN and s.insert is not None]
        if not watched:
            raise ClientError(f"the plan swaps no block of {WATCHED_CHAIN}, the chain the camera sees")
        wrong = replace(watched[0], insert=look_alike(watched[0], shelf()))
        report["wrong_swap"] = {"planned": watched[0].describe(), "done": wrong.describe(),
                                "chain": wrong.chain, "position": wrong.position}
        write_sequence(sequences, "reconfigure", plan["swaps"], f"{BUILT_FOR} gripper to {TARGET_NAME}")
        say(f"run 1: the plan's {len(plan['swaps'])} swaps, one done wrong ({wrong.describe()})")
        wrongly_built = with_block(plan["target"], WATCHED_CHAIN, wrong.position, wrong.insert)
        report["wrong_run"] = run_with_operator(client, "reconfigure", wrongly_built, plan["target"])
        fix = Swap(WATCHED_CHAIN, wrong.position, wrong.insert, watched[0].insert, watched[0].rotation_steps)
        write_sequence(sequences, "correct_swap", [fix], f"correct {WATCHED_CHAIN} to {TARGET_NAME}")
        say(f"run 2: the correction ({fix.describe()}), done right")
        report["corrected_run"] = run_with_operator(client, "correct_swap", plan["target"], plan["target"])

    run_stack(out, params, scenario, report, nodes=(), client_class=ReconfigureClient)
    report["recording"] = analyse(recording, out, title=f"{BUILT_FOR} gripper reconfigured for the {TARGET_OBJECT}")
    report["duration_s"] = time.monotonic() - started
    (out / "summary.json").write_text(json.dumps(report, indent=2, default=float))
    ok = print_summary(report, out)
    return 0 if ok else 1


def caught_before_hv(report: dict) -> bool:
    """The wrong swap ended the first run at its swap step, naming the watched chain's block, with no channel
    energised."""
    wrong, run_1 = report.get("wrong_swap"), report.get("wrong_run")
    if not (wrong and run_1):
        return False
    position = wrong["position"]
    return (not run_1["success"] and run_1["failed_step"] == "swap" and run_1["peak_voltage_v"] < DE_ENERGISED
            and f"chain {WATCHED_CHAIN}: block {position + 1}:" in run_1["message"])



def print_summary(report: dict, out: Path) -> bool:
    print("\n=== reconfiguration demo summary ===")
    for finger_set, design in report.get("designs", {}).items():
        for side in ("left", "right"):
            print(f"{BUILT_FOR} gripper {finger_set:>5} {side:<5} IDs {design[side]['design_ids']}")
    plan = report.get("plan")
    if plan:
        chosen = plan["points"][report["max_swaps"]]
        print(f"plan: {plan['message']} ({plan['solve_time_s']:.2f} s); chosen <= {report['max_swaps']} swaps: "
              f"{chosen['swaps']} swaps, objective {chosen['objective_m']:.3f} m (bound {chosen['lower_bound_m']:.3f} m"
              f"{', certified' if chosen['certified'] else ''})")
        for text in plan["swaps"]:
            print(f"  {text}")
    run_1, run_2 = report.get("wrong_run"), report.get("corrected_run")
    caught = caught_before_hv(report)
    if run_1:
        print(f"wrong swap ({report['wrong_swap']['done']}): {run_1['status']} at step '{run_1['failed_step']}', "
              f"peak {run_1['peak_voltage_v']:.0f} V -> {'caught before HV' if caught else 'NOT CAUGHT'}")
        print(f"  {run_1['message']}")
    if run_2:
        print(f"corrected: {run_2['status']}, as built after {run_2['swap_step_s'] or math.nan:.1f} s, "
              f"front closed at peak {run_2['peak_voltage_v'] / 1e3:.3f} kV")
    if "error" in report:
        print(f"FAILED: {report['error']}")
    print(f"recording: {out / 'run.mcap'} ({sum(report['recording']['message_counts'].values())} messages)")
    print(f"plots: {out / 'pareto.png'}, {out / 'recording.png'}; summary: {out / 'summary.json'}")
    print(f"total {report['duration_s']:.1f} s")
    return ("error" not in report and caught and bool(run_2) and run_2["success"]
            and run_2["peak_voltage_v"] > CLOSE_VOLTAGE - DE_ENERGISED)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.demo_reconfigure",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/reconfigure"), help="output folder")
    parser.add_argument("--swaps", type=int, default=4, help="swap budget of the chosen plan point (default 4)")
    parser.add_argument("--time-budget", type=float, default=5.0, help="planner time budget [s] (default 5)")
    args = parser.parse_args(argv)
    if not 1 <= args.swaps <= 8:
        parser.error(f"--swaps {args.swaps}: between 1 and 8 (the front pair has 8 blocks)")
    if not args.time_budget > 0:
        parser.error(f"--time-budget {args.time_budget}: a positive number of seconds")
    return run(args.out.resolve(), args.swaps, args.time_budget)


if __name__ == "__main__":
    sys.exit(main())
