"""Result, progress and run control shared by the design optimizers (scipy.optimize conventions)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from planner.objectives import COLLISION_PENALTY


class Status(IntEnum):
    CERTIFIED = 0  # the optimum is proven (exact search finished)
    FINISHED = 1  # the method ran to completion; optimality not certified
    TIME_BUDGET = 2
    CANCELED = 3
    INFEASIBLE = 4  # every design examined collides with the object or exceeds the inventory


MESSAGES = {
    Status.CERTIFIED: "optimum certified",
    Status.FINISHED: "finished; optimality not certified",
    Status.TIME_BUDGET: "time budget exhausted; best design so far returned",
    Status.CANCELED: "canceled: callback raised StopIteration",
    Status.INFEASIBLE: "no collision-free design within the inventory found; the least bad one is returned",
}


@dataclass
class DesignOptimizeResult:
    """Outcome of a design optimization, like scipy's OptimizeResult.

    ``x`` is (N, 2) integers: design ID and rotation step (k x 30 degrees) of each block, base first.
    ``fun`` is the objective [m] (plus 1e11 per collision); ``lower_bound`` a proven lower bound on the
    optimum (equal to ``fun`` when ``optimal``; -inf when the method proves none).
    """

    x: np.ndarray
    fun: float
    success: bool
    status: Status
    message: str
    nit: int
    nfev: int
    optimal: bool
    lower_bound: float
    solve_time: float
    shapes: np.ndarray = field(repr=False)  # (N,) distinct-shape index of each block
    base: int = 0  # index of the chosen base position among the target's candidates

    @property
    def design_ids(self) -> tuple[int, ...]:
        return tuple(int(i) for i in self.x[:, 0])

    @property
    def rotation_steps(self) -> tuple[int, ...]:
        return tuple(int(k) for k in self.x[:, 1])


@dataclass(frozen=True)
class Progress:
    """What a callback receives: estimated fraction done, best objective so far [m], evaluations, time [s]."""

    fraction: float
    best_cost: float
    nfev: int
    elapsed: float


class Stop(Exception):
    """Raised inside an optimizer to end the run early with ``status``."""

    def __init__(self, status: Status):
        super().__init__(status.name)
        self.status = status


class RunControl:
    """Time budget and callback of one run: ``check`` raises Stop when the run must end."""

    def __init__(self, time_budget: float | None, callback):
        if time_budget is not None and not (np.isfinite(time_budget) and time_budget > 0):
            raise ValueError(f"time_budget must be a positive number of seconds or None, got {time_budget!r}")
        if callback is not None and not callable(callback):
            raise ValueError("callback must be callable")
        self.started = time.perf_counter()
        self.time_budget = time_budget
        self.callback = callback

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    def check_time(self) -> None:
        if self.time_budget is not None and self.elapsed > self.time_budget:
            raise Stop(Status.TIME_BUDGET)

    def report(self, fraction: float, best_cost: float, nfev: int, timed: bool = True) -> None:
        """Give the callback a Progress; StopIteration from it cancels the run. ``timed`` False: the time
        budget is not checked (a step that must finish once begun)."""
        if timed:
            self.check_time()
        if self.callback is not None:
            try:
                self.callback(Progress(min(max(fraction, 0.0), 1.0), float(best_cost), nfev, self.elapsed))
            except StopIteration:
                raise Stop(Status.CANCELED) from None


def make_result(space, shapes, rotations, cost, status: Status, *, base, nit, nfev, lower_bound,
                control) -> DesignOptimizeResult:
    """Assemble a result; the message adds the numbers. ``success``: a usable design (collision-free, within
    the inventory) is returned, also when the time budget ended the run; ``optimal`` says whether it is
    proven best."""
    cost = float(cost)  # a numpy scalar would make ``success`` a numpy bool, which ROS messages reject
    shapes = np.asarray(shapes, dtype=np.int64)
    ids = space.design_ids(shapes)
    x = np.stack([np.array(ids, dtype=np.int64), np.asarray(rotations, dtype=np.int64)], axis=1)
    if status in (Status.CERTIFIED, Status.FINISHED) and cost >= COLLISION_PENALTY:
        status = Status.INFEASIBLE
    optimal = status == Status.CERTIFIED
    message = f"{MESSAGES[status]} (cost {cost:.6g} m"
    if np.isfinite(lower_bound) and not optimal:
        message += f", lower bound {lower_bound:.6g} m"
    message += ")"
    return DesignOptimizeResult(
        x=x,
        fun=cost,
        success=status in (Status.CERTIFIED, Status.FINISHED) or status == Status.TIME_BUDGET and cost < COLLISION_PENALTY,
        status=status,
        message=message,
        nit=nit,
        nfev=nfev,
        optimal=optimal,
        lower_bound=float(cost if optimal else lower_bound),
        solve_time=control.elapsed,
        shapes=shapes,
        base=int(base),
    )

