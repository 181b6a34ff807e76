"""Brute force for reconfiguration plans, at the level of design IDs: every gripper the shelf and the robot's
blocks can make, its objective, and its swaps (positions whose block or snap-fit changes)."""
import itertools
from collections import Counter

import numpy as np

from planner import design
from planner.assembly import ROTATION_STEP
from planner.contours import extract_contours
from planner.generated_objects import PIXEL_SIZE, lumpy_object
from planner.kinematics import chain_shape
from planner.objectives import COLLISION_PENALTY, evaluate
from planner.optimize import design_costs, design_space
from planner.table import load_table

TABLE = load_table()
ROWS, COLS = np.mgrid[:320, :200]


def generated_contours(kind: str, seed: int):
    """An object the planner has not seen: an ellipse, a convex polygon or a lumpy union of ellipses."""
    rng = np.random.default_rng(seed)
    if kind == "ellipse":
        mask = ((ROWS - 150) / rng.uniform(40, 75)) ** 2 + ((COLS - 100) / rng.uniform(28, 60)) ** 2 < 1.0
    elif kind == "polygon":
        angles = np.sort(rng.uniform(0, 2 * np.pi, 7))
        radii = rng.uniform(35, 70, 7)
        corners = np.stack([150 + radii * np.sin(angles), 100 + radii * np.cos(angles) * 0.8], axis=1)
        inside = np.ones(ROWS.shape, bool)
        for (r0, c0), (r1, c1) in zip(corners, np.roll(corners, -1, axis=0)):  # the convex hull's half planes
            inside &= (c1 - c0) * (ROWS - r0) - (r1 - r0) * (COLS - c0) <= 0
        mask = inside if inside.sum() > 2000 else ((ROWS - 150) / 50) ** 2 + ((COLS - 100) / 40) ** 2 < 1.0
    else:
        mask = lumpy_object(seed)
    return extract_contours(mask, PIXEL_SIZE)


def _finger_target(item, side):
    return design.finger_problems(item.contours, item.base_offsets, item.contour_spacing,
                                  item.contact_tolerance_m)[side][0]


def _cost_of(targets, weights, theta, length):
    """Weighted objective of planar fingers theta, length (n, N) (signed theta: a block bent to the other
    side), each object at its best base; inf where a finger collides at every base."""
    total = np.zeros(len(theta))
    for weight, target in zip(weights, targets):
        best = np.full(len(theta), np.inf)
        shape = chain_shape(theta, length, 0.0)
        for base in target.bases:
            cost = evaluate(target, shape.points + base, shape.rotations[..., -1, :, :], shape.positions[..., -1, :]
                            + base, (theta, length, np.full(len(theta), base[0])))
            best = np.minimum(best, np.where(cost.collision, np.inf, cost.total))
        total += weight * best
    return total


def finger_options(slot, chain, objects, ids, stiff_ids):
    """(design ID tuples, their cost, their swaps) of one finger: every upright finger of ``ids`` (soft blocks
    not at forced-stiff positions), and the finger as built when a block sits at another snap-fit."""
    space = design_space(TABLE, len(chain.blocks))
    shape_of = {d: s for s, m in enumerate(space.members) for d in m}
    targets = [_finger_target(o, slot.side) for o in objects]
    weights = [o.weight for o in objects]
    tuples = [t for t in itertools.product(ids, repeat=len(chain.blocks))
              if all(t[k] in stiff_ids for k in range(slot.num_stiff_top))]
    now = [(b.design_id, b.rotation_steps) for b in chain.blocks]
    swaps = [sum((d, 0) != b for d, b in zip(t, now)) for t in tuples]
    costs = np.zeros(len(tuples))
    if tuples:
        shapes = np.array([[shape_of[d] for d in t] for t in tuples])
        for weight, target in zip(weights, targets):
            bases = len(target.bases)
            per = design_costs(target, space, np.repeat(shapes, bases, axis=0), np.zeros((len(tuples) * bases,
                                                                                           shapes.shape[1]), int),
                               np.tile(np.arange(bases), len(tuples))).reshape(len(tuples), bases).min(axis=1)
            costs += weight * np.where(per >= COLLISION_PENALTY, np.inf, per)
    rotations = np.array([b.rotation_steps for b in chain.blocks])
    if (rotations.any() and set(rotations.tolist()) <= {0, 6}
            and all(chain.blocks[k].design_id in stiff_ids for k in range(slot.num_stiff_top))):
        theta = TABLE.theta0[[list(TABLE.ids).index(b.design_id) for b in chain.blocks]]
        length = TABLE.rod_length[[list(TABLE.ids).index(b.design_id) for b in chain.blocks]]
        signed = np.cumprod(np.where(rotations == 6, -1.0, 1.0)) * theta
        tuples.append(tuple(b.design_id for b in chain.blocks))
        swaps.append(0)
        costs = np.append(costs, _cost_of(targets, weights, signed[None], length[None]))
    return tuples, costs, np.array(swaps)


def plan_brute_force(robot, shelf, objects, slots):
    """best[s]: the lowest objective of a gripper with at most s swaps whose blocks the shelf and the robot's
    finger blocks supply (inf: none)."""
    chains = [robot.chain(s.chain) for s in slots]
    pool = Counter({d: n for d, n in shelf.items() if n > 0}) + Counter(b.design_id for c in chains for b in c.blocks)
    ids = sorted(pool)
    stiff_ids = {int(i) for i, d in zip(TABLE.ids, TABLE.rod_diameter) if d >= design.DEFAULT_MIN_STIFF_ROD_DIAMETER
                 * (1 - 1e-9)}
    total = sum(len(c.blocks) for c in chains)
    best = np.full(total + 1, np.inf)
    limit = np.array([pool[d] for d in ids])
    fingers = []
    for slot, chain in zip(slots, chains):
        tuples, costs, swaps = finger_options(slot, chain, objects, ids, stiff_ids)
        keep = np.isfinite(costs)
        counts = np.array([[Counter(t)[d] for d in ids] for t in tuples], int).reshape(len(tuples), len(ids))
        fingers.append((counts[keep], costs[keep], swaps[keep]))
    combined = [(np.zeros((1, len(ids)), int), np.zeros(1), np.zeros(1, int))]
    for counts, costs, swaps in fingers:
        previous = combined[-1]
        rows = []
        for i in range(len(previous[1])):
            fit = np.all(previous[0][i] + counts <= limit, axis=1)
            rows.append((previous[0][i] + counts[fit], previous[1][i] + costs[fit], previous[2][i] + swaps[fit]))
        combined.append(tuple(np.concatenate([r[k] for r in rows]) if rows else np.zeros(0) for k in range(3)))
    _, costs, swaps = combined[-1]
    for s in range(total + 1):
        within = costs[swaps <= s]
        best[s] = within.min(initial=np.inf)
    return best


def path_brute_force(chain, shelf, path):
    """best[s] for a chain along ``path``: every chain of the shelf's and the chain's own blocks, at every
    snap-fit rotation; a swap is a position whose block or rotation changes."""
    from planner.objectives import path_target
    pool = Counter({d: n for d, n in shelf.items() if n > 0}) + Counter(b.design_id for b in chain.blocks)
    blocks = len(chain.blocks)
    space = design_space(TABLE, blocks, allow_rotation=True)
    shape_of = {d: s for s, m in enumerate(space.members) for d in m}
    tuples = [t for t in itertools.product(sorted(pool), repeat=blocks)
              if all(n <= pool[d] for d, n in Counter(t).items())]
    rotations = np.array(list(itertools.product(range(12), repeat=blocks)))
    target = path_target(path)
    now_ids = np.array([b.design_id for b in chain.blocks])
    now_rotations = np.array([b.rotation_steps for b in chain.blocks])
    best = np.full(blocks + 1, np.inf)
    for t in tuples:
        shapes = np.repeat(np.array([[shape_of[d] for d in t]]), len(rotations), axis=0)
        costs = design_costs(target, space, shapes, rotations, np.zeros(len(rotations), int))
        swaps = ((np.array(t) != now_ids) | (rotations != now_rotations)).sum(axis=1)
        for s in range(blocks + 1):
            best[s] = min(best[s], costs[swaps <= s].min(initial=np.inf))
    return best
