"""Fit one block structure to a silhouette: bending angles (and a small base correction) by robust least squares.

Parameters x = [theta_1 .. theta_N [rad], base shift x, y [pixels], base turn [rad]]. Residuals, in units of
the outline noise ``edge_sigma``: the signed distance of every visible outline sample of the model from the
observed outline, and weak Gaussian priors on each angle (its design's, wide: they only keep the fit well
posed) and on the base correction. A *bounded* fit keeps every angle within its designs' angles +- the
manufacturing tolerance (the chain as built, as its hypothesis says); a *free* fit measures the angles.

1. ``track``: block by block from the base, each angle by a coarse-to-fine grid search over both bending
   sides against that block's own outline samples and the start of the next block (the chain is serial, so
   every block starts where the fitted ones end), on the silhouette's coarse distance map. This finds the
   basin even when many blocks deviate by several degrees.
2. ``refine``: ``scipy.optimize.least_squares`` (trust region reflective, Cauchy loss so an occluded part
   only loosely pulls, the tolerance as bounds for a bounded fit) from the tracked start; Jacobian = outline
   normal x d(sample)/d(parameter), the sample derivatives from one batched outline call.
3. ``score``: the robust cost both ways (model outline -> image outline and image outline -> model
   outline, each weighted by the outline length it stands for) plus the base prior; this is what hypotheses
   (bounded fits) are compared by.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from estimation.hypotheses import Hypothesis
from estimation.outline import (
    OutlineLayout,
    centreline,
    outline_from_centreline,
    outline_layout,
    outline_points,
    start_frame,
    visible,
)
from planner.kinematics import block_transforms
from estimation.silhouette import Silhouette
from estimation.view import ImagePose

FD_STEP = 1e-6  # [rad] forward-difference step of the sample derivatives
BASE_PARAMETERS = 3
DENSE_SPACING = 0.5  # [pixels] the model outline's spacing when image outline is measured against it


@dataclass(frozen=True)
class FitOptions:
    sample_spacing: float = 3.0  # [pixels] between outline samples along the centreline
    edge_sigma: float = 1.0  # [pixels] noise of an outline position
    robust_scale: float = 2.0  # Cauchy loss scale, in units of edge_sigma
    # A built block's angle lies within +-this of its design's (manufacturing: the paper's blocks measured
    # within +-2.5 deg of their design before the membrane went on) [rad]
    angle_tolerance: float = math.radians(2.5)
    angle_prior_sigma: float = math.radians(10.0)  # weak prior of a known block's angle in the fits [rad]
    unknown_angle_sigma: float = math.radians(20.0)  # prior width of a block whose design is open [rad]
    base_shift_sigma: float = 1e-3  # [m] prior on the base position correction
    base_turn_sigma: float = math.radians(1.0)  # [rad] prior on the base angle correction
    fit_base: bool = True
    track_range: float = math.radians(60.0)  # the grid spans +-this around zero, both bending sides [rad]
    # grid steps of the tracking, coarse to fine: each level searches +-the previous step around the best so far
    track_steps: tuple[float, ...] = (math.radians(5.0), math.radians(1.0), math.radians(0.25))
    track_stride: int = 2  # tracking scores every this many outline samples
    lookahead: float = 0.5  # tracking also scores this fraction of the next block (it pins the end heading)
    max_nfev: int = 40
    xtol: float = 1e-4  # least_squares tolerances: steps of 1e-4 rad move the outline far less than a pixel
    ftol: float = 1e-4
    unexplained_distance: float = 2.0  # [pixels] an outline point farther than this is unexplained
    misfit_distance: float = 1.0  # [pixels] outline farther than this from the other outline misfits its block
    occlusion_start: float = 2.0  # [edge_sigma] model outline outside the silhouette beyond this counts less:
    occlusion_span: float = 1.0  # an occluder may hide it; its residual saturates at start + span


@dataclass(frozen=True)
class Score:
    total: float  # image terms + the base prior (no mistake penalty)
    model_to_image: float
    image_to_model: float
    prior: float
    unexplained_length: float  # [m] of image outline the model leaves unexplained (chain where the model has none)
    hidden_length: float  # [m] of model outline where the image shows no chain (occluded, or not there)
    block_residual: np.ndarray  # (N,) RMS distance of each block's outline from the image outline [m]
    block_misfit: np.ndarray  # (N,) outline farther than misfit_distance from the other outline, both ways, by block [m]
    block_unexplained: np.ndarray  # (N,) the same farther than unexplained_distance [m]


@dataclass(frozen=True)
class Fit:
    hypothesis: Hypothesis
    x: np.ndarray
    theta_std: np.ndarray  # (N,) [rad]
    score: Score
    nfev: int

    @property
    def theta(self) -> np.ndarray:
        return self.x[: len(self.hypothesis.blocks)]


def cauchy(residual: np.ndarray, scale: float) -> np.ndarray:
    """scipy's Cauchy loss per residual: 0.5 C^2 ln(1 + (r / C)^2)."""
    return 0.5 * scale**2 * np.log1p((residual / scale) ** 2)


def bounded(z: np.ndarray, start: float, span: float) -> np.ndarray:
    """Residual of model outline lying outside the silhouette (z > 0, in edge_sigma): unchanged up to
    ``start``, then saturating smoothly at start + span. Occluders remove chain pixels, never add them, so
    a part of the model the image does not show costs at most a bounded amount; a part of the image the
    model does not cover (z < 0) keeps its full cost."""
    over = np.maximum(z - start, 0.0)
    return np.where(z > start, start + span * np.tanh(over / span), z)


def bounded_slope(z: np.ndarray, start: float, span: float) -> np.ndarray:
    return np.where(z > start, 1.0 - np.tanh(np.maximum(z - start, 0.0) / span) ** 2, 1.0)


def _polyline_lengths(points: np.ndarray, slices) -> np.ndarray:
    """Length of outline each sample stands for: half of each adjacent segment, per open polyline."""
    lengths = np.zeros(len(points))
    for part in slices:
        step = np.linalg.norm(np.diff(points[part], axis=0), axis=1)
        lengths[part] = np.concatenate([[0.0], step]) * 0.5 + np.concatenate([step, [0.0]]) * 0.5
    return lengths


class ChainModel:
    """One hypothesis in one image: parameters -> outline samples (image frame), residuals and Jacobian."""

    def __init__(self, hypothesis: Hypothesis, silhouette: Silhouette, pose: ImagePose, options: FitOptions,
                 within_tolerance: bool = True, layout: OutlineLayout | None = None):
        self.hypothesis = hypothesis
        self.silhouette = silhouette
        self.pose = pose
        self.options = options
        self.pixel = silhouette.pixel_size
        self.layout = layout or outline_layout(hypothesis.length, hypothesis.phi, options.sample_spacing * self.pixel)
        self.blocks = self.layout.blocks
        self.mean, self.sigma = hypothesis.prior(options.angle_prior_sigma, options.unknown_angle_sigma)
        self.size = self.blocks + (BASE_PARAMETERS if options.fit_base else 0)
        self.lower, self.upper = np.full(self.size, -np.inf), np.full(self.size, np.inf)
        if within_tolerance:
            self.lower[: self.blocks], self.upper[: self.blocks] = hypothesis.bounds(options.angle_tolerance)
        self.shown = np.ones(len(self.layout.block), dtype=bool)
        self.edge = options.edge_sigma * self.pixel  # [m]
        self._cache = None

    def start(self) -> np.ndarray:
        return np.concatenate([self.mean, np.zeros(self.size - self.blocks)])

    def _base(self, x) -> tuple[np.ndarray, float]:
        if not self.options.fit_base:
            return np.zeros(2), 0.0
        return np.asarray(x[self.blocks : self.blocks + 2]) * self.pixel, float(x[self.blocks + 2])

    def image_points(self, x, theta=None) -> np.ndarray:
        """Outline samples in the image (..., M, 2) [m]; ``theta`` (..., N) overrides the angles of x."""
        shift, turn = self._base(x)
        angles = x[: self.blocks] if theta is None else theta
        return self.pose.to_image(outline_points(self.layout, angles), shift, turn)

    def update_visibility(self, x) -> bool:
        """Recompute which samples are hidden by the body itself or a known occluder; True if that changed."""
        shown = visible(self.layout, x[: self.blocks]) & ~self.silhouette.occluded(self.image_points(x))
        changed = not np.array_equal(shown, self.shown)
        self.shown = shown
        self._cache = None
        return changed

    def _evaluate(self, x):
        key = np.asarray(x, dtype=float).tobytes()
        if self._cache is None or self._cache[0] != key:
            points = self.image_points(x)[self.shown]
            distance, normals = self.silhouette.signed_distance(points)
            self._cache = (key, points, distance, normals)
        return self._cache[1:]

    def prior_residuals(self, x) -> np.ndarray:
        parts = [(x[: self.blocks] - self.mean) / self.sigma]
        if self.options.fit_base:
            shift, turn = self._base(x)
            parts.append(np.append(shift / self.options.base_shift_sigma, turn / self.options.base_turn_sigma))
        return np.concatenate(parts)

    def outline_residuals(self, distance: np.ndarray) -> np.ndarray:
        return bounded(distance / self.edge, self.options.occlusion_start, self.options.occlusion_span)

    def residuals(self, x) -> np.ndarray:
        _, distance, _ = self._evaluate(x)
        return np.concatenate([self.outline_residuals(distance), self.prior_residuals(x)])

    def jacobian(self, x) -> np.ndarray:
        points, distance, normals = self._evaluate(x)
        normals = normals * bounded_slope(distance / self.edge, self.options.occlusion_start, self.options.occlusion_span)[:, None]
        theta = np.asarray(x[: self.blocks], dtype=float)
        batch = theta + np.vstack([np.zeros(self.blocks), FD_STEP * np.eye(self.blocks)])
        moved = self.image_points(x, batch)[:, self.shown]  # (N + 1, M, 2)
        derivative = (moved[1:] - moved[:1]) / FD_STEP  # (N, M, 2)
        image_rows = np.einsum("nmk,mk->mn", derivative, normals) / self.edge
        jacobian = np.zeros((len(points) + self.size, self.size))
        jacobian[: len(points), : self.blocks] = image_rows
        prior = np.arange(self.blocks)
        jacobian[len(points) + prior, prior] = 1.0 / self.sigma
        if self.options.fit_base:
            shift, _ = self._base(x)
            arm = points - (self.pose.position + shift)
            columns = slice(self.blocks, self.size)
            jacobian[: len(points), columns] = np.column_stack([
                normals[:, 0] * self.pixel, normals[:, 1] * self.pixel, normals[:, 1] * arm[:, 0] - normals[:, 0] * arm[:, 1],
            ]) / self.edge
            rows = len(points) + self.blocks + np.arange(BASE_PARAMETERS)
            jacobian[rows, self.blocks + np.arange(BASE_PARAMETERS)] = [
                self.pixel / self.options.base_shift_sigma, self.pixel / self.options.base_shift_sigma, 1.0 / self.options.base_turn_sigma,
            ]
        return jacobian


class TrackingWindow:
    """Block k and the start of block k + 1 over a grid of block k's angle, in block k's start frame; the
    rows (angles) are computed when first asked for."""

    def __init__(self, layout: OutlineLayout, samples: np.ndarray, grid: np.ndarray, following: float):
        self.layout, self.samples, self.grid, self.following = layout, samples, grid, following
        count = len(grid)
        self.local = np.empty((count, len(samples), 2))  # the judging samples' outline (planar layouts)
        self.local_ready = np.zeros(count, dtype=bool)
        self.points = np.empty((count, layout.centreline_samples, 3))  # centreline and tangents (any layout)
        self.tangent = np.empty_like(self.points)
        self.centreline_ready = np.zeros(count, dtype=bool)

    def _angles(self, rows: np.ndarray) -> np.ndarray:
        return np.column_stack([self.grid[rows], np.full((rows.size, self.layout.blocks - 1), self.following)])

    def outline(self, rows: np.ndarray, rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
        """The judging samples' outline (rows, S, 2) in the chain frame, the window placed at ``rotation``,
        ``position`` (block k's start frame)."""
        if self.layout.planar and _in_plane(rotation):  # a rigid motion of the x-z plane
            missing = rows[~self.local_ready[rows]]
            if missing.size:
                self.local[missing] = outline_points(self.layout, self._angles(missing))[:, self.samples]
                self.local_ready[missing] = True
            return self.local[rows] @ rotation[0::2, 0::2].T + position[0::2]
        missing = rows[~self.centreline_ready[rows]]
        if missing.size:
            self.points[missing], self.tangent[missing] = centreline(self.layout, self._angles(missing))
            self.centreline_ready[missing] = True
        return outline_from_centreline(self.layout, self.points[rows], self.tangent[rows], (rotation, position))[:, self.samples]


class TrackingTables:
    """Tracking windows by block structure, shared by every hypothesis fitted to one image."""

    def __init__(self, options: FitOptions, pixel_size: float):
        finest = options.track_steps[-1]
        self.options = options
        self.spacing = options.sample_spacing * pixel_size
        self.grid = np.arange(-options.track_range, options.track_range + 0.5 * finest, finest)
        self.levels = [max(1, round(step / finest)) for step in options.track_steps]  # grid indices per step
        self._windows = {}

    def allowed(self, lower: float, upper: float) -> np.ndarray:
        """Indices of the grid angles within [lower, upper] (to the nearest grid step; at least the nearest one)."""
        half = 0.5 * (self.grid[1] - self.grid[0])
        inside = np.flatnonzero((self.grid >= lower - half) & (self.grid <= upper + half))
        return inside if inside.size else np.array([int(np.argmin(np.abs(self.grid - np.clip(0.0, lower, upper))))])

    def window(self, model: ChainModel, k: int) -> TrackingWindow:
        stop = min(k + 2, model.blocks)
        following = float(model.mean[k + 1]) if stop > k + 1 else 0.0
        key = (tuple(np.round(model.layout.length[k:stop], 9)), tuple(np.round(model.layout.phi[k:stop], 9)),
               round(following, 9), k == 0)
        if key not in self._windows:
            self._windows[key] = self._build(model.layout.length[k:stop], model.layout.phi[k:stop], following, k == 0)
        return self._windows[key]

    def _build(self, length, phi, following: float, base: bool) -> TrackingWindow:
        layout = outline_layout(length, phi, self.spacing)
        p, f = layout.centreline_samples, len(layout.face)
        index = np.arange(len(layout.block))
        # block k's sides, the chain's base face if k = 0, the chain's tip face if k is the last block
        own = (layout.block == 0) & ((index < 2 * p) | (base & (index < 2 * p + f)))
        if layout.blocks == 1:
            own |= index >= 2 * p + f
        ahead = (index < 2 * p) & (layout.block == 1) & (layout.fraction <= self.options.lookahead)
        samples = np.flatnonzero(own | ahead)[:: self.options.track_stride]
        return TrackingWindow(layout, samples, self.grid, following)


def _in_plane(rotation: np.ndarray) -> bool:
    return abs(abs(rotation[1, 1]) - 1.0) < 1e-12


def track(model: ChainModel, x: np.ndarray, first: int = 0, tables: TrackingTables | None = None) -> tuple[np.ndarray, int]:
    """Angles of blocks ``first``.. found one after the other by a coarse-to-fine grid search over both
    bending sides (within the tolerance for a bounded model; the next block held at its prior); returns x and
    the number of shapes evaluated."""
    x = np.array(x, dtype=float)
    tables = tables or TrackingTables(model.options, model.pixel)
    shift, turn = model._base(x)
    layout = model.layout
    rotation, position = start_frame(x[: model.blocks], layout.length, layout.phi, first)
    evaluations = 0
    for k in range(first, model.blocks):
        window = tables.window(model, k)
        allowed = tables.allowed(model.lower[k], model.upper[k])
        chosen, span = None, len(tables.grid)
        for level in tables.levels:
            near = allowed if chosen is None else allowed[np.abs(allowed - chosen) <= span]
            rows = near[near % level == 0]
            rows, span = (rows if rows.size else near), level
            image = model.pose.to_image(window.outline(rows, rotation, position), shift, turn)
            cost = cauchy(model.outline_residuals(model.silhouette.coarse_distance(image)), model.options.robust_scale)
            cost = np.sum(cost * ~model.silhouette.occluded(image), axis=1)
            cost += 0.5 * ((tables.grid[rows] - model.mean[k]) / model.sigma[k]) ** 2
            chosen = int(rows[np.argmin(cost)])
            evaluations += len(rows)
        x[k] = np.clip(tables.grid[chosen], model.lower[k], model.upper[k])
        step = block_transforms(x[k : k + 1], layout.length[k : k + 1], layout.phi[k : k + 1])[0]  # block k's end
        rotation, position = rotation @ step[:3, :3], rotation @ step[:3, 3] + position
    return x, evaluations


def quick_cost(model: ChainModel, x: np.ndarray) -> float:
    """Robust model -> image cost on the coarse distance map: ranks tracked candidates cheaply."""
    points = model.image_points(x)
    cost = cauchy(model.outline_residuals(model.silhouette.coarse_distance(points)), model.options.robust_scale)
    return float(np.sum(cost * ~model.silhouette.occluded(points)))


def refine(model: ChainModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Robust least squares from x; returns x, the angles' standard deviations [rad] and evaluations."""
    evaluations = 0
    x = np.clip(x, model.lower, model.upper)
    for _ in range(2):  # a second pass only if the fitted shape hides other samples than the start did
        model.update_visibility(x)
        result = least_squares(
            model.residuals, x, jac=model.jacobian, bounds=(model.lower, model.upper), method="trf", loss="cauchy",
            f_scale=model.options.robust_scale, x_scale="jac", max_nfev=model.options.max_nfev, xtol=model.options.xtol,
            ftol=model.options.ftol,
        )
        x, evaluations = result.x, evaluations + result.nfev
        if not model.update_visibility(x):
            break
    return x, _angle_std(model, result), evaluations


def _angle_std(model: ChainModel, result) -> np.ndarray:
    """Standard deviations of the angles from the Gauss-Newton covariance, with the residual variance
    estimated from the fit and inflated by the residuals' integrated autocorrelation time along the
    outline (pixel quantisation makes neighbouring samples err alike, more so at coarse resolution)."""
    jacobian = result.jac
    image = result.fun[: len(result.fun) - model.size]
    variance = 2.0 * result.cost / max(len(result.fun) - model.size, 1)
    try:
        covariance = np.linalg.pinv(jacobian.T @ jacobian) * variance * correlation_time(image)
    except np.linalg.LinAlgError:
        return np.full(model.blocks, np.inf)
    return np.sqrt(np.maximum(np.diag(covariance)[: model.blocks], 0.0))


def correlation_time(residuals: np.ndarray, max_lag: int = 100) -> float:
    """1 + 2 sum of the autocorrelations, summed up to the first lag where they stop being positive."""
    centred = residuals - residuals.mean()
    power = float(np.dot(centred, centred))
    if power <= 0.0:
        return 1.0
    total = 1.0
    for lag in range(1, min(max_lag, len(centred) - 1)):
        rho = float(np.dot(centred[lag:], centred[:-lag])) / power
        if rho <= 0.0:
            break
        total += 2.0 * rho
    return total


def score(model: ChainModel, x: np.ndarray) -> Score:
    """Both-way robust outline cost, priors, and the unexplained and hidden outline at parameters x."""
    options = model.options
    silhouette = model.silhouette
    layout = model.layout
    theta = x[: model.blocks]
    shift, turn = model._base(x)
    spacing = options.sample_spacing * model.pixel
    chain_points, chain_normals = outline_points(layout, theta, normals=True)
    points = model.pose.to_image(chain_points, shift, turn)
    normals = model.pose.directions_to_image(chain_normals, turn)
    shown = visible(layout, theta) & ~silhouette.occluded(points)
    lengths = _polyline_lengths(points, layout.polylines)
    distance, _ = silhouette.signed_distance(points[shown])
    scale, far = options.robust_scale, options.unexplained_distance * model.pixel
    model_cost = float(np.sum(lengths[shown] / spacing * cauchy(model.outline_residuals(distance), scale)))
    # image -> model: signed distance of each image outline vertex from the model outline (densified to
    # DENSE_SPACING; the sign from the nearest sample's outward normal); image outline inside the model may be
    # occluded
    dense, dense_normals, dense_blocks = _densified(points, normals, shown, layout, DENSE_SPACING * model.pixel)
    gap, nearest = cKDTree(dense).query(silhouette.outline)
    inside = np.sum((silhouette.outline - dense[nearest]) * dense_normals[nearest], axis=1) < 0.0
    image_z = np.where(inside, model.outline_residuals(gap), gap / model.edge)
    counted = silhouette.lengths if silhouette.outline_occluded is None else silhouette.lengths * ~silhouette.outline_occluded
    image_cost = float(np.sum(counted / spacing * cauchy(image_z, scale)))
    prior = 0.0  # the angles' priors only keep the fit well posed: hypotheses are compared by the image
    if options.fit_base:
        base = model.prior_residuals(x)[model.blocks:]
        prior += 0.5 * float(np.dot(base, base))
    blocks = layout.block[shown]
    residual = np.array([np.sqrt(np.mean(distance[blocks == k] ** 2)) if np.any(blocks == k) else np.nan for k in range(model.blocks)])

    def beyond(limit: float) -> np.ndarray:
        return (np.bincount(blocks, weights=lengths[shown] * (np.abs(distance) > limit), minlength=model.blocks)
                + np.bincount(dense_blocks[nearest], weights=counted * (gap > limit), minlength=model.blocks))

    image_far = gap > far
    return Score(
        total=model_cost + image_cost + prior,
        model_to_image=model_cost,
        image_to_model=image_cost,
        prior=prior,
        unexplained_length=float(np.sum(lengths[shown] * (distance < -far)) + np.sum(counted[image_far & ~inside])),
        hidden_length=float(np.sum(lengths[shown] * (distance > far)) + np.sum(counted[image_far & inside])),
        block_residual=residual,
        block_misfit=beyond(options.misfit_distance * model.pixel),
        block_unexplained=beyond(far),
    )


def _densified(points: np.ndarray, normals: np.ndarray, shown: np.ndarray, layout: OutlineLayout, spacing: float):
    """The visible model outline as points at most ``spacing`` [m] apart along each polyline (the samples at
    a straight cap's ends lie far apart), each with the normal and the block of the sample its piece starts at."""
    first, last, pieces = [], [], []
    for part in layout.polylines:
        index = np.arange(part.start, part.stop)
        pairs = shown[index[:-1]] & shown[index[1:]]
        start, end = index[:-1][pairs], index[1:][pairs]
        first += [start, index[shown[index]]]  # the segments, and every visible sample itself (a polyline's last)
        last += [end, index[shown[index]]]
        pieces += [np.ceil(np.linalg.norm(points[end] - points[start], axis=1) / spacing), np.ones(np.count_nonzero(shown[index]))]
    first, last = np.concatenate(first), np.concatenate(last)
    count = np.maximum(np.concatenate(pieces), 1).astype(int)
    owner = np.repeat(np.arange(len(first)), count)
    t = ((np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)) / np.repeat(count, count))[:, None]
    start = first[owner]
    return points[start] * (1 - t) + points[last[owner]] * t, normals[start], layout.block[start]


def block_residuals(model: ChainModel, x: np.ndarray) -> np.ndarray:
    """(N,) RMS distance [m] of each block's visible model outline from the image outline at parameters x."""
    points = model.image_points(x)
    shown = visible(model.layout, x[: model.blocks]) & ~model.silhouette.occluded(points)
    distance, _ = model.silhouette.signed_distance(points[shown])
    blocks = model.layout.block[shown]
    return np.array([np.sqrt(np.mean(distance[blocks == k] ** 2)) if np.any(blocks == k) else np.nan
                     for k in range(model.blocks)])


def inherited_start(model: ChainModel, parent_x: np.ndarray, first: int) -> np.ndarray:
    """Start of a hypothesis derived from a fitted one (its free fit: a bounded fit of a wrong chain may
    have bent the base to make up for it): the parent's angles of the (shared) blocks before ``first``
    within this model's bounds, the prior beyond, the parent's base correction."""
    x = model.start()
    x[:first] = parent_x[:first]
    extra = model.size - model.blocks
    if extra:
        x[model.blocks :] = parent_x[len(parent_x) - extra :]
    return np.clip(x, model.lower, model.upper)


def fit(hypothesis: Hypothesis, silhouette: Silhouette, pose: ImagePose, options: FitOptions,
        start: np.ndarray | None = None, first: int = 0, tables: TrackingTables | None = None,
        within_tolerance: bool = True) -> Fit:
    """Track blocks ``first``.. from ``start`` (default: the prior), refine by least squares, score."""
    model = ChainModel(hypothesis, silhouette, pose, options, within_tolerance)
    x, nfev = track(model, model.start() if start is None else start, first, tables)
    return _refined(model, x, nfev)


def refit(fitted: Fit, silhouette: Silhouette, pose: ImagePose, options: FitOptions, within_tolerance: bool) -> Fit:
    """The same hypothesis refined from a fit's parameters, bounded or free (no tracking: it starts close)."""
    return _refined(ChainModel(fitted.hypothesis, silhouette, pose, options, within_tolerance), fitted.x, 0)


def held_within_bounds(fitted: Fit, silhouette: Silhouette, pose: ImagePose, options: FitOptions) -> Fit:
    """A fit's parameters clipped into its hypothesis's bounds and scored there, not refined (so its angles'
    uncertainties are unknown: NaN)."""
    model = ChainModel(fitted.hypothesis, silhouette, pose, options)
    x = np.clip(fitted.x, model.lower, model.upper)
    return Fit(hypothesis=fitted.hypothesis, x=x, theta_std=np.full(model.blocks, np.nan), score=score(model, x), nfev=1)


def _refined(model: ChainModel, x: np.ndarray, nfev: int) -> Fit:
    x, theta_std, evaluations = refine(model, x)
    return Fit(hypothesis=model.hypothesis, x=x, theta_std=theta_std, score=score(model, x), nfev=nfev + evaluations)
