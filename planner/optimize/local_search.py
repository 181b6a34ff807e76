"""Block-by-block local search: improve complete designs by changing one block (or the base) at a time.

Every sweep tries, for each block position in turn, all allowed shapes and rotations there (and every
candidate base position), keeping the best change; sweeps repeat until none improves. All candidates of a
position are evaluated at once, for several starting designs in parallel.
"""
from __future__ import annotations

import numpy as np

from planner.objectives import ShapeTarget
from planner.optimize.pso import design_costs
from planner.optimize.result import RunControl
from planner.optimize.space import DesignSpace


def polish(target: ShapeTarget, space: DesignSpace, shapes: np.ndarray, rotations: np.ndarray, bases: np.ndarray,
           control: RunControl, samples_per_block: int, max_sweeps: int = 20):
    """Local optimum reached from each start (K, N); returns shapes, rotations, bases, costs and evaluations."""
    shapes, rotations, bases = shapes.copy(), rotations.copy(), bases.copy()
    cost = design_costs(target, space, shapes, rotations, bases, samples_per_block)
    nfev = len(cost)
    for _ in range(max_sweeps):
        improved = False
        for position in range(space.num_blocks + 1):
            control.check_time()
            if position == space.num_blocks:  # the base
                options = np.arange(len(target.bases))
                trial_shapes = np.repeat(shapes[:, None], len(options), axis=1)
                trial_rotations = np.repeat(rotations[:, None], len(options), axis=1)
                trial_bases = np.broadcast_to(options, (len(bases), len(options))).copy()
            else:
                choice = np.repeat(space.choices[position], space.rotations)
                turn = np.tile(np.arange(space.rotations), len(space.choices[position]))
                trial_shapes = np.repeat(shapes[:, None], len(choice), axis=1)
                trial_rotations = np.repeat(rotations[:, None], len(choice), axis=1)
                trial_shapes[:, :, position] = choice
                trial_rotations[:, :, position] = turn
                trial_bases = np.repeat(bases[:, None], len(choice), axis=1)
            trial = design_costs(target, space, trial_shapes, trial_rotations, trial_bases, samples_per_block)
            nfev += trial.size
            pick = np.argmin(trial, axis=1)
            rows = np.arange(len(cost))
            better = trial[rows, pick] < cost - 1e-12
            if better.any():
                improved = True
                shapes[better] = trial_shapes[rows, pick][better]
                rotations[better] = trial_rotations[rows, pick][better]
                bases[better] = trial_bases[rows, pick][better]
                cost[better] = trial[rows, pick][better]
        if not improved:
            break
    return shapes, rotations, bases, cost, nfev
