"""Particle swarm optimization of a chain design, as in the paper (section 2.3, ref. 43).

Each particle holds one continuous coordinate per block in [0, number of allowed shapes), when rotations
are allowed one per block in [0, 12), and one for the choice among the target's base positions; flooring
decodes them to shapes, snap-fit rotations and a base. Velocities follow the standard inertia-weight update ``v = w v + c1 r1 (p_best - x) + c2 r2 (g_best - x)``. Blocks
beyond the inventory cost the penalty k each, like a collision. A heuristic: never certified optimal.
"""
from __future__ import annotations

import numpy as np

from planner.assembly import ROTATION_STEP
from planner.kinematics import DEFAULT_SAMPLES_PER_BLOCK, chain_shape
from planner.objectives import COLLISION_PENALTY, ShapeTarget, evaluate
from planner.optimize.result import DesignOptimizeResult, RunControl, Status, Stop, make_result
from planner.optimize.space import DesignSpace

DEFAULT_OPTIONS = {
    "swarm_size": 40,
    "maxiter": 150,
    "inertia": 0.7298,  # constriction-equivalent weights (Clerc and Kennedy)
    "c1": 1.49618,  # pull toward the particle's own best
    "c2": 1.49618,  # pull toward the swarm's best
    "samples_per_block": DEFAULT_SAMPLES_PER_BLOCK,
}


def design_costs(target: ShapeTarget, space: DesignSpace, shapes: np.ndarray, rotations: np.ndarray,
                 base=0, samples_per_block: int = DEFAULT_SAMPLES_PER_BLOCK) -> np.ndarray:
    """Objective (...) of designs given as shape indices and rotation steps (..., N) and base index (...),
    inventory penalty included."""
    theta, length = space.theta[shapes], space.length[shapes]
    shape = chain_shape(theta, length, rotations * ROTATION_STEP, samples_per_block=samples_per_block)
    offset = target.bases[base]
    blocks = None if target.body is None else (theta, length, offset[..., 0])  # finger bodies are planar
    cost = evaluate(target, shape.points + offset[..., None, :], shape.rotations[..., -1, :, :],
                    shape.positions[..., -1, :] + offset, blocks)
    return cost.total + COLLISION_PENALTY * space.excess(shapes)


def _check_options(options: dict | None) -> dict:
    unknown = set(options or {}) - set(DEFAULT_OPTIONS)
    if unknown:
        raise ValueError(f"options: unknown keys {sorted(unknown)}; known: {sorted(DEFAULT_OPTIONS)}")
    settings = DEFAULT_OPTIONS | (options or {})
    for key in ("swarm_size", "maxiter"):
        if not (isinstance(settings[key], (int, np.integer)) and settings[key] >= 1):
            raise ValueError(f"options[{key!r}] must be an integer >= 1, got {settings[key]!r}")
    for key in ("inertia", "c1", "c2"):
        if not (np.isfinite(settings[key]) and settings[key] >= 0):
            raise ValueError(f"options[{key!r}] must be a finite number >= 0, got {settings[key]!r}")
    return settings


def solve_pso(target: ShapeTarget, space: DesignSpace, *, rng: np.random.Generator | int | None = None,
              options: dict | None = None, time_budget=None, callback=None) -> DesignOptimizeResult:
    """Minimise the objective of ``target`` over ``space`` with a particle swarm; reproducible for a seed."""
    settings = _check_options(options)
    rng = np.random.default_rng(rng)
    control = RunControl(time_budget, callback)
    blocks = space.num_blocks
    rotating = space.rotations > 1
    sizes = np.array([len(c) for c in space.choices] + [space.rotations] * (blocks if rotating else 0)
                     + [len(target.bases)])
    upper = sizes - 1e-9

    def decode(x):
        index = np.floor(x).astype(np.int64)
        shapes = np.stack([space.choices[i][index[:, i]] for i in range(blocks)], axis=1)
        rotations = index[:, blocks:-1] if rotating else np.zeros_like(shapes)
        return shapes, rotations, index[:, -1]

    def cost(x):
        return design_costs(target, space, *decode(x), samples_per_block=settings["samples_per_block"])

    swarm = settings["swarm_size"]
    position = rng.uniform(0.0, upper, size=(swarm, len(sizes)))
    velocity = rng.uniform(-0.5, 0.5, size=position.shape) * sizes
    own_best, own_cost = position.copy(), cost(position)
    nfev, nit, status = swarm, 0, Status.FINISHED
    best = int(np.argmin(own_cost))
    try:
        control.report(0.0, own_cost[best], nfev)
        for nit in range(1, settings["maxiter"] + 1):
            r1, r2 = rng.random((2,) + position.shape)
            velocity = (settings["inertia"] * velocity + settings["c1"] * r1 * (own_best - position)
                        + settings["c2"] * r2 * (own_best[best] - position))
            velocity = np.clip(velocity, -sizes / 2, sizes / 2)
            position = np.clip(position + velocity, 0.0, upper)
            current = cost(position)
            nfev += swarm
            improved = current < own_cost
            own_best[improved], own_cost[improved] = position[improved], current[improved]
            best = int(np.argmin(own_cost))
            control.report(nit / settings["maxiter"], own_cost[best], nfev)
    except Stop as stop:
        status = stop.status
    shapes, rotations, base = decode(own_best[best : best + 1])
    return make_result(space, shapes[0], rotations[0], own_cost[best], status, base=base[0], nit=nit, nfev=nfev,
                       lower_bound=-np.inf, control=control)
