"""Estimate a chain's block angles from a side-view silhouette and judge whether it was built as believed.

``estimate_chain`` measures the believed chain's angles (a free fit, ``estimation.fit``) and fits it again
with every angle held within its design's manufacturing tolerance (a bounded fit: the chain as built as
believed). Hypotheses are compared by how well their bounded fits explain the silhouette (robust outline
cost both ways, in pixels): if the tolerance costs more than ``mistake_penalty`` (some block needs an angle
no offset within the tolerance gives) or part of the outline stays unexplained, every chain with one
assembly mistake more (``estimation.hypotheses.alternatives``) is fitted the same way, and the one with the
lowest penalised score (``mistake_penalty`` per mistake) wins if it beats the believed chain; this repeats up
to ``max_mistakes`` times. A mistake further along the chain than the first misfitting block cannot cause
that misfit, so such candidates are not tried. The reported angles are the winner's free fit.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, fields
from enum import IntEnum

import numpy as np

from estimation.fit import (
    ChainModel,
    Fit,
    FitOptions,
    TrackingTables,
    block_residuals,
    fit,
    held_within_bounds,
    inherited_start,
    quick_cost,
    refit,
    track,
)
from estimation.hypotheses import DesignBook, Hypothesis, MistakeKind, alternatives, believed_hypothesis
from estimation.outline import is_planar
from estimation.silhouette import Silhouette, check_base, silhouette_from_image
from estimation.view import ImagePose
from planner.assembly import Chain
from planner.block_calibration import BlockCalibration
from planner.kinematics import BLOCK_RADIUS, CAP_LENGTH
from planner.table import load_table


@dataclass(frozen=True)
class EstimateOptions(FitOptions):
    mistake_penalty: float = 5.0  # score (outline cost, see docs/estimation.md) a mistake must save to be reported
    max_mistakes: int = 2
    out_of_plane: bool = True  # also consider rotation steps that take a block out of the image plane
    search_trigger: float = 8.0  # [pixels] of outline beyond misfit_distance at one block that start the search for mistakes
    max_unexplained: float = 0.1  # fraction of the image outline that may stay unexplained for success
    refine_candidates: int = 5  # candidates refined by least squares after tracking


BASE_SHIFT_LIMIT = 3.0  # base corrections beyond this many prior sigmas mean a wrong base pose


class Status(IntEnum):
    AS_BUILT = 0  # the believed chain explains the image
    MISTAKES_FOUND = 1  # a chain with the reported mistakes explains it
    UNEXPLAINED = 2  # no chain tried explains the image; the closest is reported


MESSAGES = {
    Status.AS_BUILT: "as built",
    Status.MISTAKES_FOUND: "assembly mistakes found",
    Status.UNEXPLAINED: "the silhouette is not explained by the believed chain or one with up to max_mistakes mistakes",
}


@dataclass(frozen=True)
class Mistake:
    """One assembly mistake. ``position`` is the 0-based index of the believed block concerned (base first);
    for an extra block, the believed block it was inserted before (the block count: after the last)."""

    kind: MistakeKind
    position: int
    believed_design_id: int | None = None
    likely_design_ids: tuple[int, ...] = ()  # WRONG_DESIGN, EXTRA_BLOCK: most likely first
    believed_rotation_step: int | None = None
    likely_rotation_steps: tuple[int, ...] = ()  # WRONG_ROTATION: the steps a side view cannot tell apart
    evidence: float = 0.0  # score saved by assuming this mistake (beyond the penalty it pays)

    def describe(self) -> str:
        block = f"block {self.position + 1}"
        if self.kind is MistakeKind.WRONG_DESIGN:
            return f"{block}: design {self.likely_design_ids[0]} instead of {self.believed_design_id} (candidates {list(self.likely_design_ids)})"
        if self.kind is MistakeKind.WRONG_ROTATION:
            steps = " or ".join(str(s) for s in self.likely_rotation_steps)
            return f"{block}: rotation step {steps} instead of {self.believed_rotation_step} (x 30 deg)"
        if self.kind is MistakeKind.MISSING_BLOCK:
            return f"{block} (design {self.believed_design_id}) is missing"
        where = "after the last block" if self.believed_design_id is None else f"before {block}"
        return f"an extra block {where}: likely design {self.likely_design_ids[0]} (candidates {list(self.likely_design_ids)})"


@dataclass(frozen=True)
class BlockEstimate:
    """One block of the chain that explains the image (base first)."""

    position: int
    design_id: int
    rotation_steps: int
    serial: str
    believed_position: int | None  # its index in the believed chain; None for an extra block
    theta: float  # estimated bending angle [rad]
    theta_std: float  # its standard deviation [rad]
    predicted_theta: float  # from the look-up table at the voltage (+ calibration) [rad]
    residual_predicted: float  # RMS distance of the predicted outline from the image's, along this block [m]
    residual: float  # the same after the fit [m]

    @property
    def offset(self) -> float:
        return self.theta - self.predicted_theta


@dataclass(frozen=True)
class ChainEstimate:
    """Result of ``estimate_chain`` (scipy.optimize conventions: success, status, message)."""

    success: bool
    status: Status
    message: str
    mistakes: tuple[Mistake, ...]
    blocks: tuple[BlockEstimate, ...]
    chain: Chain  # the chain that explains the image
    base_shift: tuple[float, float]  # correction of the base position found by the fit [m]
    base_turn: float  # correction of the base angle [rad]
    residual: float  # RMS distance of the fitted outline from the image's [m]
    unexplained_length: float  # image outline the fitted chain does not explain [m]
    hidden_length: float  # outline of the fitted chain the image does not show (occluded or absent) [m]
    outline_length: float  # the image outline's length [m]
    hypotheses: int  # chains fitted
    nfev: int
    solve_time: float  # [s]

    @property
    def as_built(self) -> bool:
        return self.status is Status.AS_BUILT

    @property
    def theta(self) -> np.ndarray:
        return np.array([b.theta for b in self.blocks])

    @property
    def theta_std(self) -> np.ndarray:
        return np.array([b.theta_std for b in self.blocks])

    def to_dict(self) -> dict:
        """JSON-ready structure, SI units."""
        return {
            "success": self.success,
            "status": self.status.name.lower(),
            "message": self.message,
            "mistakes": [
                {
                    "kind": m.kind.value,
                    "position": m.position,
                    "believed_design_id": m.believed_design_id,
                    "likely_design_ids": list(m.likely_design_ids),
                    "believed_rotation_step": m.believed_rotation_step,
                    "likely_rotation_steps": list(m.likely_rotation_steps),
                    "evidence": m.evidence,
                    "description": m.describe(),
                }
                for m in self.mistakes
            ],
            "blocks": [
                {
                    "position": b.position,
                    "design_id": b.design_id,
                    "rotation_steps": b.rotation_steps,
                    "serial": b.serial,
                    "believed_position": b.believed_position,
                    "theta_rad": b.theta,
                    "theta_std_rad": b.theta_std,
                    "predicted_theta_rad": b.predicted_theta,
                    "offset_rad": b.offset,
                    "residual_predicted_m": b.residual_predicted,
                    "residual_m": b.residual,
                }
                for b in self.blocks
            ],
            "base_shift_m": list(self.base_shift),
            "base_turn_rad": self.base_turn,
            "residual_m": self.residual,
            "unexplained_length_m": self.unexplained_length,
            "hidden_length_m": self.hidden_length,
            "outline_length_m": self.outline_length,
            "hypotheses": self.hypotheses,
            "nfev": self.nfev,
            "solve_time_s": self.solve_time,
        }


def make_options(options) -> EstimateOptions:
    """EstimateOptions from None, an EstimateOptions or a mapping of its fields (unknown keys: ValueError)."""
    if options is None:
        return EstimateOptions()
    if isinstance(options, EstimateOptions):
        return options
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a mapping or EstimateOptions, got {type(options).__name__}")
    known = {f.name for f in fields(EstimateOptions)}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ValueError(f"unknown options {unknown}; known: {sorted(known)}")
    return EstimateOptions(**options)


def calibration_offsets(chain: Chain, calibration) -> dict[str, float]:
    """Serial -> angle offset [rad] for the chain's blocks, from a BlockCalibration or a mapping."""
    if calibration is None:
        return {}
    if isinstance(calibration, BlockCalibration):
        return {b.serial: calibration.offset_for(b.serial, b.design_id) for b in chain.blocks if b.serial}
    if isinstance(calibration, Mapping):
        return {str(k): float(v) for k, v in calibration.items()}
    raise ValueError(f"calibration must be a BlockCalibration or a mapping serial -> offset [rad], got {type(calibration).__name__}")


class _Search:
    """The fits of one image: the believed chain, then chains with more mistakes."""

    def __init__(self, silhouette: Silhouette, pose: ImagePose, book: DesignBook, believed: Chain, options: EstimateOptions):
        self.silhouette, self.pose, self.book, self.believed, self.options = silhouette, pose, book, believed, options
        self.hypotheses = 0
        self.nfev = 0
        self.tables = TrackingTables(options, silhouette.pixel_size)

    def penalised(self, candidate: Fit) -> float:
        return candidate.score.total + self.options.mistake_penalty * len(candidate.hypothesis.changes)

    def fit(self, hypothesis: Hypothesis, start: np.ndarray | None = None, first: int = 0,
            within_tolerance: bool = True) -> Fit:
        result = fit(hypothesis, self.silhouette, self.pose, self.options, start, first, self.tables, within_tolerance)
        return self._counted(result)

    def _counted(self, result: Fit) -> Fit:
        self.hypotheses += 1
        self.nfev += result.nfev
        return result

    def free(self, bounded: Fit) -> Fit:
        """The bounded fit's chain measured: its angles free (weak prior only)."""
        return self._counted(refit(bounded, self.silhouette, self.pose, self.options, within_tolerance=False))

    def bounded(self, free: Fit) -> Fit:
        """The free fit's chain with every angle within the tolerance: the same fit if they all are; else its
        angles held at the tolerance if that explains the image (costs less than a mistake more than the free
        fit, no outline misfit: then the optimum within the bounds could only be better), else refitted."""
        lower, upper = free.hypothesis.bounds(self.options.angle_tolerance)
        if np.all((free.theta >= lower) & (free.theta <= upper)):
            return free
        held = held_within_bounds(free, self.silhouette, self.pose, self.options)
        if self.first_misfit(held, free) is None:
            return held
        return self._counted(refit(free, self.silhouette, self.pose, self.options, within_tolerance=True))

    def tracked(self, hypothesis: Hypothesis, parent: Fit) -> tuple[float, Hypothesis, np.ndarray]:
        """Quick look at a candidate: track its changed blocks, and the block before (the parent's angle there
        may make up for the mistake), from the parent's free fit; coarse cost only."""
        model = ChainModel(hypothesis, self.silhouette, self.pose, self.options)
        first = max(hypothesis.start - 1, 0)
        x, evaluations = track(model, inherited_start(model, parent.x, first), first, self.tables)
        self.hypotheses += 1
        self.nfev += evaluations
        return quick_cost(model, x) + self.options.mistake_penalty * len(hypothesis.changes), hypothesis, x

    def first_misfit(self, current: Fit, free: Fit) -> int | None:
        """Believed index of the block a mistake must lie at or before, or None if the bounded fit explains the
        image: no block's outline strays beyond ``misfit_distance`` from the image's for more than
        ``search_trigger``, and holding the angles within the tolerance costs less than a mistake.

        Where either fit's outline strays beyond ``unexplained_distance``, the first such block, of either
        fit, whichever lies further along (a bounded fit may turn the base or bend earlier blocks to make up
        for a mistake, and so misfit before it); where holding the angles costs more than a mistake, the
        last block whose free angle lies beyond its tolerance; else (a subtle misfit) the last block."""
        trigger = self.options.search_trigger * self.silhouette.pixel_size
        blocks = current.hypothesis.blocks
        lower, upper = current.hypothesis.bounds(self.options.angle_tolerance)
        tolerance_costs = current.score.total - free.score.total > self.options.mistake_penalty
        beyond = tolerance_costs & ((free.theta < lower) | (free.theta > upper))
        if not beyond.any() and not (current.score.block_misfit > trigger).any():
            return None
        firsts = [int(np.argmax(far)) for far in (current.score.block_unexplained > trigger, free.score.block_unexplained > trigger)
                  if far.any()]
        if beyond.any():
            firsts.append(int(np.flatnonzero(beyond)[-1]))
        index = max(firsts) if firsts else len(blocks) - 1
        positions = [b.believed for b in blocks[: index + 1] if b.believed is not None]
        return positions[-1] if positions else 0

    def improve(self, current: Fit, free: Fit) -> Fit | None:
        """The best chain with one mistake more than ``current`` if it scores better, else None.

        Every candidate is tracked from the block before its first change (within the tolerance; a block whose
        design is open within its designs' angles +- the tolerance) and ranked by a coarse cost; the best few
        are refined and scored. Rotations out of the image plane are tried only if no in-plane candidate
        explains the image.
        """
        misfit = self.first_misfit(current, free)
        if misfit is None:
            return None
        candidates = alternatives(current.hypothesis, len(self.believed.blocks), self.book,
                                  out_of_plane=self.options.out_of_plane, last_position=misfit + 1)
        in_plane = [h for h in candidates if is_planar(h.phi) or not is_planar(current.hypothesis.phi)]
        best = self._best_of(free, in_plane)
        if len(in_plane) < len(candidates) and self.first_misfit(best, self.free(best)) is not None:
            best = min(best, self._best_of(free, [h for h in candidates if h not in in_plane]), key=self.penalised)
        return best if self.penalised(best) < self.penalised(current) else None

    def _best_of(self, parent: Fit, candidates: list[Hypothesis]) -> Fit:
        ranked = sorted((self.tracked(h, parent) for h in candidates), key=lambda item: item[0])
        return min((self.fit(h, x, len(h.blocks)) for _, h, x in ranked[: self.options.refine_candidates]), key=self.penalised)


def estimate_chain(image, chain: Chain, pixel_size: float, pose: ImagePose, *, voltage: float = 0.0,
                   calibration=None, table=None, threshold: float | None = None, occlusion=None,
                   options=None) -> ChainEstimate:
    """Block angles of ``chain`` seen in a side-view ``image``, and whether it was built as believed.

    image: path or 2D array, the chain brighter than the background (binary, or grey with ``threshold``);
    pixel_size [m / pixel]; pose: where the chain's base sits in the image (``ImagePose``); voltage [V] on
    the chain's channel; calibration: ``BlockCalibration`` or mapping serial -> angle offset [rad];
    occlusion: optional boolean array of the image's shape, True where a known object may hide the chain.
    ValueError naming the problem for a bad image (see ``silhouette_from_image``), a chain that does
    not start at the given base, or unknown options.
    """
    started = time.perf_counter()
    options = make_options(options)
    if not isinstance(chain, Chain):
        raise ValueError(f"chain must be a planner.assembly.Chain, got {type(chain).__name__}")
    if not isinstance(pose, ImagePose):
        raise ValueError(f"pose must be an estimation.ImagePose (base centre [m], growth angle [rad]), got {type(pose).__name__}")
    if not (isinstance(voltage, (int, float)) and math.isfinite(voltage) and voltage >= 0):
        raise ValueError(f"voltage must be a finite number >= 0 V, got {voltage!r}")
    table = load_table() if table is None else table
    book = DesignBook.at(table, float(voltage))
    believed = believed_hypothesis(chain, book, calibration_offsets(chain, calibration))
    silhouette = silhouette_from_image(image, pixel_size, threshold, occlusion=occlusion)
    check_base(silhouette, pose, BLOCK_RADIUS, CAP_LENGTH)
    search = _Search(silhouette, pose, book, chain, options)
    free = search.fit(believed, within_tolerance=False)
    _check_base_correction(free, options, silhouette.pixel_size)
    current = first = search.bounded(free)
    for _ in range(options.max_mistakes):
        better = search.improve(current, free)
        if better is None:
            break
        current, free = better, search.free(better)
    return _result(search, first, current, free, time.perf_counter() - started)


def _check_base_correction(first: Fit, options: EstimateOptions, pixel_size: float) -> None:
    """ValueError if the fit had to move the base far: the chain does not start at the given base."""
    if not options.fit_base:
        return
    blocks = len(first.hypothesis.blocks)
    shift = float(np.hypot(*first.x[blocks : blocks + 2])) * pixel_size
    turn = abs(float(first.x[blocks + 2]))
    if shift > BASE_SHIFT_LIMIT * options.base_shift_sigma or turn > BASE_SHIFT_LIMIT * options.base_turn_sigma:
        raise ValueError(
            f"the chain does not start at the given base: the silhouette fits a base {1e3 * shift:.1f} mm away "
            f"({shift / pixel_size:.0f} pixels) and turned by {math.degrees(turn):.1f} deg; check the base position, "
            "angle and mirrored flag"
        )


def _mistakes(search: _Search, current: Fit, first: Fit, measured: Fit) -> tuple[Mistake, ...]:
    believed = search.believed.blocks
    gain = search.penalised(first) - search.penalised(current)
    mistakes = []
    for change in current.hypothesis.changes:
        designs = () if change.block is None else _likely_designs(search, measured, change.block)
        known = change.position < len(believed)
        mistakes.append(Mistake(
            kind=change.kind,
            position=change.position,
            believed_design_id=believed[change.position].design_id if known else None,
            likely_design_ids=designs if change.kind in (MistakeKind.WRONG_DESIGN, MistakeKind.EXTRA_BLOCK) else (),
            believed_rotation_step=believed[change.position].rotation_steps if known else None,
            likely_rotation_steps=change.rotation_steps,
            evidence=gain,
        ))
    return tuple(sorted(mistakes, key=lambda m: m.position))


def _likely_designs(search: _Search, measured: Fit, block: int) -> tuple[int, ...]:
    """The designs a block's measured angle allows: within the tolerance plus three times the angle's
    uncertainty, nearest first (designs closer than that cannot be told apart by the image)."""
    reach = search.options.angle_tolerance + 3.0 * float(measured.theta_std[block])
    return measured.hypothesis.ranked_designs(block, float(measured.theta[block]), reach)


def _result(search: _Search, first: Fit, current: Fit, measured: Fit, elapsed: float) -> ChainEstimate:
    """The verdict (status, mistakes) from ``current``; designs, angles, residuals and base from ``measured``
    (the same chain's free fit)."""
    hypothesis = current.hypothesis
    designs = hypothesis.nearest_designs(measured.theta)
    predicted_fit = _predicted_residuals(search, hypothesis, designs)
    blocks = []
    for k, spec in enumerate(hypothesis.blocks):
        predicted = spec.angles[spec.designs.index(designs[k])]
        blocks.append(BlockEstimate(
            position=k, design_id=int(designs[k]), rotation_steps=spec.rotation_steps, serial=spec.serial,
            believed_position=spec.believed, theta=float(measured.theta[k]), theta_std=float(measured.theta_std[k]),
            predicted_theta=float(predicted), residual_predicted=float(predicted_fit[k]),
            residual=float(measured.score.block_residual[k]),
        ))
    outline_length = float(search.silhouette.lengths.sum())
    explained = current.score.unexplained_length <= search.options.max_unexplained * outline_length
    mistakes = _mistakes(search, current, first, measured) if hypothesis.changes else ()
    status = Status.UNEXPLAINED if not explained else (Status.MISTAKES_FOUND if mistakes else Status.AS_BUILT)
    message = MESSAGES[status]
    if mistakes:
        message += ": " + "; ".join(m.describe() for m in mistakes)
    if current.score.hidden_length > search.options.search_trigger * search.silhouette.pixel_size:
        message += f" ({1e3 * current.score.hidden_length:.0f} mm of the chain's outline not seen: occluded?)"
    shift = measured.x[len(blocks) : len(blocks) + 2] * search.silhouette.pixel_size if search.options.fit_base else np.zeros(2)
    return ChainEstimate(
        success=status is not Status.UNEXPLAINED,
        status=status,
        message=message,
        mistakes=mistakes,
        blocks=tuple(blocks),
        chain=hypothesis.to_chain(search.believed, measured.theta),
        base_shift=(float(shift[0]), float(shift[1])),
        base_turn=float(measured.x[len(blocks) + 2]) if search.options.fit_base else 0.0,
        residual=float(np.sqrt(np.nanmean(measured.score.block_residual**2))),
        unexplained_length=current.score.unexplained_length,
        hidden_length=current.score.hidden_length,
        outline_length=outline_length,
        hypotheses=search.hypotheses,
        nfev=search.nfev,
        solve_time=elapsed,
    )


def _predicted_residuals(search: _Search, hypothesis: Hypothesis, designs) -> np.ndarray:
    """Per block RMS outline distance of the table's prediction (no fit) from the image [m]."""
    model = ChainModel(hypothesis, search.silhouette, search.pose, search.options)
    x = model.start()
    x[: model.blocks] = [spec.angles[spec.designs.index(d)] for spec, d in zip(hypothesis.blocks, designs)]
    return block_residuals(model, x)
