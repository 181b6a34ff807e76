"""Planner node: designs fingers for an object image and chains along 3D paths (planner.design), and plans
reconfigurations from the robot as built (planner.reconfigure).

Optimizations run in service and action callbacks on a reentrant group of a MultiThreadedExecutor, so other
requests, parameter services and shutdown are served meanwhile. A bad request gets success=false and the
core's message; the node carries on. Shutting down cancels running optimizations; the actions
(``planner/design_fingers``, ``planner/plan_reconfiguration``) also report progress and can be canceled.
"""
from __future__ import annotations

import sys
import threading
import time
from functools import partial

import numpy as np

from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from softblock_interfaces import action
from softblock_interfaces.msg import Assembly as AssemblyMsg
from softblock_interfaces.srv import DesignFingers, DesignPath

from planner import design, reconfigure, reconfigure_path
from planner.contours import extract_contours, load_mask
from planner.table import load_table

from .conversions import (assembly_from_msg, assembly_msg, designed_chain_msg, inventory_from_lists,
                          mask_from_image, path_from_points)
from .qos import LATCHED
from .goals import settle
from .parameters import Param, declare
from .paths import resolve_path
from .runner import run_node, where

DEFAULT_METHOD = "exact"
MAX_PLAN_OBJECTS = 16  # objects of one plan goal
MAX_BASE_OFFSETS = 64  # candidate base offsets of one object
READY = "ready, serving"  # logged once every service and action is offered
# Finger base frames in the object frame (x right, z up): the finger grows downward (+z -> -z) and
# bends toward the object (+x -> +x for the left finger, -x for the right one).
FINGER_BASE_ORIENTATION = {"left": (1.0, 0.0, 0.0, 0.0), "right": (0.0, 1.0, 0.0, 0.0)}
PARAMETERS = (
    Param("default_time_budget_s", 30.0, "time budget of a request that gives 0; 0 = no limit", "s", 0.0, 3600.0),
    Param("max_blocks", 8, "largest number of blocks per finger or chain a request may ask for", low=1,
          high=design.MAX_BLOCKS, kind=int),
    Param("table_path", "", "look-up table file; empty = the planner's default table", kind=str),
    Param("prepare_finger_search", True, "before serving, compile the finger search and load its lookahead fields "
          "for the gripper's (blocks, stiff top) configurations within max_blocks, so that the first request "
          "does not wait for them", kind=bool),
)


class PlannerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("planner", **kwargs)
        self._settings = declare(self, PARAMETERS)
        table_path = self._settings["table_path"]
        self._table = load_table(resolve_path(table_path)) if table_path else load_table()
        if self._settings["prepare_finger_search"]:
            self._prepare_finger_search()
        self._stopping = threading.Event()
        group = ReentrantCallbackGroup()
        self.create_service(DesignFingers, "planner/design_fingers", partial(self._serve, self._design_fingers),
                            callback_group=group)
        self.create_service(DesignPath, "planner/design_path", partial(self._serve, self._design_path),
                            callback_group=group)
        self._built: AssemblyMsg | None = None  # the latest assembly/current, the default robot of a plan
        self.create_subscription(AssemblyMsg, "assembly/current", self._on_assembly, LATCHED, callback_group=group)
        for kind, name, solve in ((action.DesignFingers, "planner/design_fingers", self._design_fingers),
                                  (action.PlanReconfiguration, "planner/plan_reconfiguration", self._plan)):
            ActionServer(self, kind, name, execute_callback=partial(self._execute, kind, solve),
                         cancel_callback=lambda _goal: CancelResponse.ACCEPT, callback_group=group)
        self.get_logger().info(f"{READY}, table of {len(self._table.ids)} designs")

    def _prepare_finger_search(self) -> None:
        configurations = [c for c in design.GRIPPER_CONFIGURATIONS if c[0] <= self._settings["max_blocks"]]
        started = time.perf_counter()
        design.prepare_finger_search(configurations, table=self._table)
        self.get_logger().info(f"finger search prepared for (blocks, stiff top) {configurations} "
                               f"({time.perf_counter() - started:.1f} s)")

    def destroy_node(self):
        self._stopping.set()
        return super().destroy_node()

    def _serve(self, solve, request, response):
        """Run ``solve``; a rejected request (ValueError) becomes success=false with the reason, and so does a
        failure of the design code (logged as an error), so that every request is answered."""
        try:
            solve(request, response)
        except ValueError as error:
            response.success, response.message = False, f"request refused: {error}"
            self.get_logger().warning(response.message)
        except Exception as error:  # a bug below, but the client still gets its answer
            reason = (str(error).splitlines() or [""])[0][:200]
            response.success, response.message = False, f"request failed: {type(error).__name__}: {reason}"
            self.get_logger().error(f"{response.message} (at {where(error)})")
        return response

    def _on_assembly(self, message) -> None:
        self._built = message

    def _execute(self, kind, solve, goal_handle):
        """An action goal: ``solve`` with a callback that publishes feedback and stops on cancel or shutdown;
        the result's success and message as the service would answer them."""
        def progress(report):
            self._cancel_on_shutdown()
            if goal_handle.is_cancel_requested:
                raise StopIteration
            goal_handle.publish_feedback(self._feedback(kind, report))

        result = self._serve(partial(solve, callback=progress), goal_handle.request, kind.Result())
        settle(goal_handle, goal_handle.is_cancel_requested, result.success)
        return result

    @staticmethod
    def _feedback(kind, report):
        if kind is action.DesignFingers:
            return kind.Feedback(fraction=report.fraction, best_cost=report.best_cost, evaluations=report.nfev,
                                 elapsed=report.elapsed)
        return kind.Feedback(fraction=report.fraction, best_objective=report.best_cost, elapsed=report.elapsed)

    def _options(self, request, callback=None) -> dict:
        max_blocks = self._settings["max_blocks"]
        if not 1 <= request.num_blocks <= max_blocks:
            raise ValueError(f"num_blocks must be 1..{max_blocks}, got {request.num_blocks}")
        budget = request.time_budget or self._settings["default_time_budget_s"]
        if not budget >= 0.0:
            raise ValueError(f"time_budget must be >= 0 s, got {request.time_budget}")
        method = request.method or DEFAULT_METHOD
        if method not in design.METHODS:
            raise ValueError(f"method must be one of {', '.join(design.METHODS)}, got {method!r}")
        return dict(method=method, time_budget=budget or None,
                    seed=request.seed, table=self._table, callback=callback or self._cancel_on_shutdown)

    def _cancel_on_shutdown(self, *_):
        if self._stopping.is_set() or not self.context.ok():
            raise StopIteration

    def _design_fingers(self, request, response, callback=None) -> None:
        options = self._options(request, callback)
        self.get_logger().info(f"design_fingers: {request.num_blocks} blocks per finger, {options['method']}")
        if request.image.height:
            mask = load_mask(mask_from_image(request.image))
        elif request.image_path:
            mask = load_mask(resolve_path(request.image_path))
        else:
            raise ValueError("give an image or an image_path")
        result = design.design_fingers(
            mask, request.pixel_size, request.num_blocks, num_stiff_top=request.num_stiff_top,
            min_stiff_rod_diameter=request.min_stiff_rod_diameter or design.DEFAULT_MIN_STIFF_ROD_DIAMETER,
            inventory=inventory_from_lists(request.inventory_ids, request.inventory_counts),
            contact_tolerance_m=request.contact_tolerance, **options)
        response.success, response.message = result.success, result.message
        response.optimal, response.solve_time = result.optimal, result.solve_time
        for side in ("left", "right"):
            finger = getattr(result, side)
            if finger is not None and len(finger.design_ids):
                base_x, base_z = finger.base
                setattr(response, side, designed_chain_msg(side, finger.design_ids, self._table,
                                                           base_position=(base_x, 0.0, base_z),
                                                           base_orientation=FINGER_BASE_ORIENTATION[side]))
                setattr(response, f"{side}_cost", float(finger.cost))
                setattr(response, f"{side}_collision", bool(finger.collision))
                setattr(response, f"{side}_min_clearance", float(finger.min_clearance_m))
                setattr(response, f"{side}_lower_bound", float(finger.lower_bound_m))
        self.get_logger().info(f"design_fingers: {result.message} ({result.solve_time:.2f} s)")

    def _plan(self, goal, result, callback) -> None:
        """planner/plan_reconfiguration: the Pareto set of swaps against the objective (a gripper for objects,
        or a trunk for a path), the chosen point's steps."""
        robot = goal.robot if goal.robot.chains else self._built
        if robot is None:
            raise ValueError("no robot given and no assembly/current received yet")
        built, _ = assembly_from_msg(robot, self._table)
        shelf = inventory_from_lists(goal.shelf_ids, goal.shelf_counts) or {}
        budget = goal.time_budget or self._settings["default_time_budget_s"]
        if not budget >= 0.0:
            raise ValueError(f"time_budget must be >= 0 s, got {goal.time_budget}")
        if goal.path:
            if goal.object_image_paths or goal.finger_chains:
                raise ValueError("give either a path (and path_chain) or objects (and finger chains), not both")
            chains = [goal.path_chain]
            self._check_max_swaps(goal, built, chains)
            self.get_logger().info(f"plan_reconfiguration: chain {goal.path_chain!r} along {len(goal.path)} points")
            plan = reconfigure_path.plan_path_reconfiguration(
                built, goal.path_chain, shelf, path_from_points(goal.path), table=self._table,
                time_budget=budget or None, callback=callback)
        else:
            objects = self._plan_objects(goal)
            slots = reconfigure.GRIPPER_SLOTS
            if goal.finger_chains:
                if not len(goal.finger_chains) == len(goal.finger_sides) == len(goal.finger_stiff_top):
                    raise ValueError("finger_chains, finger_sides and finger_stiff_top must have the same length")
                slots = tuple(reconfigure.FingerSlot(c, s, int(n))
                              for c, s, n in zip(goal.finger_chains, goal.finger_sides, goal.finger_stiff_top))
            self._check_max_swaps(goal, built, [slot.chain for slot in slots])
            self.get_logger().info(f"plan_reconfiguration: {len(objects)} objects, {len(slots)} fingers")
            plan = reconfigure.plan_reconfiguration(built, shelf, objects, slots=slots, table=self._table,
                                                    time_budget=budget or None, callback=callback)
        result.success, result.message, result.solve_time = plan.success, plan.message, plan.solve_time
        points = plan.points
        result.max_swaps = [p.max_swaps for p in points]
        result.swaps = [max(p.swaps, 0) for p in points]
        result.objectives = [float(p.objective) for p in points]
        result.lower_bounds = [float(p.lower_bound) for p in points]
        result.optimal = [bool(p.optimal) for p in points]
        chosen = points[goal.max_swaps]
        if chosen.assembly is None:
            result.success = False
            result.message += f"; no robot within the shelf with at most {chosen.max_swaps} swaps"
            return
        result.target = assembly_msg(chosen.assembly, self._table)
        steps = reconfigure.swap_steps(built, chosen.assembly, shelf)
        result.steps = [step.describe() for step in steps]
        result.step_chains = [step.chain for step in steps]
        result.step_positions = [step.position for step in steps]
        result.step_remove = [-1 if step.remove is None else step.remove for step in steps]
        result.step_insert = [-1 if step.insert is None else step.insert for step in steps]
        result.step_rotation_steps = [step.rotation_steps for step in steps]
        self.get_logger().info(f"plan_reconfiguration: {plan.message} ({plan.solve_time:.2f} s)")

    @staticmethod
    def _check_max_swaps(goal, built, chains) -> None:
        names = {c.name for c in built.chains}
        swaps_possible = sum(len(built.chain(name).blocks) for name in chains if name in names)
        if not -1 <= goal.max_swaps <= swaps_possible:
            raise ValueError(f"max_swaps must be -1..{swaps_possible}, got {goal.max_swaps}")

    def _plan_objects(self, goal) -> list:
        """The goal's objects with their own settings (parallel lists; an empty list: the default for all)."""
        paths, count = goal.object_image_paths, len(goal.object_image_paths)
        if not 1 <= count <= MAX_PLAN_OBJECTS:
            raise ValueError(f"give 1..{MAX_PLAN_OBJECTS} object_image_paths (or a path), got {count}")

        def per_object(name, values, default):
            if not len(values):
                return [default] * count
            if len(values) != count:
                raise ValueError(f"{name} must have one entry per object ({count}) or none, got {len(values)}")
            return list(values)

        sizes = per_object("pixel_sizes", goal.pixel_sizes, None)
        if None in sizes:
            raise ValueError(f"give one pixel_sizes entry per object ({count})")
        weights = per_object("weights", goal.weights, 1.0)
        tolerances = per_object("contact_tolerances", goal.contact_tolerances, 0.0)
        spacings = per_object("contour_spacings", goal.contour_spacings, design.DEFAULT_CONTOUR_SPACING)
        counts = per_object("base_offset_counts", goal.base_offset_counts, None)
        if None in counts:
            if len(goal.base_offsets):
                raise ValueError("base_offsets need base_offset_counts (how many belong to each object)")
            offsets = [design.DEFAULT_BASE_OFFSETS] * count
        else:
            if sum(counts) != len(goal.base_offsets) or not all(1 <= n <= MAX_BASE_OFFSETS for n in counts):
                raise ValueError(f"base_offset_counts must be 1..{MAX_BASE_OFFSETS} per object and add up to the "
                                 f"{len(goal.base_offsets)} base_offsets")
            ends = np.cumsum([0] + counts)
            offsets = [np.array(goal.base_offsets[a:b]) for a, b in zip(ends[:-1], ends[1:])]
        return [reconfigure.TargetObject(path, extract_contours(load_mask(resolve_path(path)), size), weight=w,
                                         base_offsets=o, contour_spacing=spacing, contact_tolerance_m=tolerance)
                for path, size, w, o, spacing, tolerance in zip(paths, sizes, weights, offsets, spacings, tolerances)]

    def _design_path(self, request, response) -> None:
        options = self._options(request)
        self.get_logger().info(f"design_path: {request.num_blocks} blocks, {options['method']}")
        result = design.design_path(path_from_points(request.path), request.num_blocks,
                                    allow_rotation=request.allow_rotation, **options)
        response.success, response.message = result.success, result.message
        response.cost, response.solve_time = float(result.cost), result.solve_time
        if len(result.design_ids):
            response.chain = designed_chain_msg("path", result.design_ids, self._table, result.rotation_steps)
        self.get_logger().info(f"design_path: {result.message} ({result.solve_time:.2f} s)")


def main(args=None):
    sys.exit(run_node(PlannerNode, "planner", executor=MultiThreadedExecutor, args=args))


if __name__ == "__main__":
    main()
