"""Fit N-term Ogden constants to uniaxial and pure-shear test data (paper eqs 4-8).

Two methods minimise the same objective, eq 8 summed over the test points, with each mode's
residuals divided by that mode's largest measured stress so both tests weigh alike:

* ``"pso"``: particle-swarm optimization as in the paper (global-best swarm with Clerc's
  constriction coefficients; scipy has no PSO and the PSO packages on PyPI are unmaintained);
* ``"least_squares"``: multi-start trust-region-reflective least squares (scipy), much faster.

Test data CSV: columns ``mode`` (``uniaxial`` or ``pure_shear``), ``stretch`` and
``nominal_stress_Pa``; see config/ogden_test_data_example.csv.
"""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from planner.ogden import pure_shear_nominal_stress, uniaxial_nominal_stress

MODES = {"uniaxial": uniaxial_nominal_stress, "pure_shear": pure_shear_nominal_stress}
STRESS_SCALE = 1e6  # optimize mu in MPa
DEFAULT_BOUNDS = {"mu": (1e-4, 1.0), "alpha": (0.5, 8.0)}  # mu [MPa], alpha [-]


@dataclass(frozen=True)
class OgdenTestData:
    uniaxial_stretch: np.ndarray
    uniaxial_stress: np.ndarray  # nominal [Pa]
    shear_stretch: np.ndarray
    shear_stress: np.ndarray  # nominal [Pa]

    def __post_init__(self) -> None:
        for mode, stretch, stress in (
            ("uniaxial", self.uniaxial_stretch, self.uniaxial_stress),
            ("pure_shear", self.shear_stretch, self.shear_stress),
        ):
            if len(stretch) != len(stress) or len(stretch) < 2:
                raise ValueError(f"{mode} data need at least 2 (stretch, stress) points of equal count")
            if not (np.all(np.isfinite(stretch)) and np.all(np.isfinite(stress))):
                raise ValueError(f"{mode} data must be finite")
            if np.any(np.asarray(stretch) < 1.0):
                raise ValueError(f"{mode} stretch must be >= 1 (tension tests)")


@dataclass(frozen=True)
class OgdenFitResult:
    mu: np.ndarray  # [Pa]
    alpha: np.ndarray
    cost: float  # eq 8 with normalised residuals, summed over all points
    success: bool
    message: str
    method: str
    n_evaluations: int  # objective evaluations (one per particle per iteration for PSO)
    elapsed: float  # wall-clock time [s]

    def stress(self, mode: str, stretch) -> np.ndarray:
        """Nominal stress [Pa] of the fitted model in ``mode`` at ``stretch``."""
        return _mode_function(mode)(self.mu, self.alpha, stretch)


def _mode_function(mode: str):
    try:
        return MODES[mode]
    except KeyError:
        raise ValueError(f"mode must be one of {sorted(MODES)}, got {mode!r}") from None


def load_test_data(path) -> OgdenTestData:
    """Read a test-data CSV (mode, stretch, nominal_stress_Pa); errors name the bad line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Ogden test data {path} not found")
    points = {mode: ([], []) for mode in MODES}
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = {"mode", "stretch", "nominal_stress_Pa"} - set(reader.fieldnames or ())
        if missing:
            raise ValueError(f"{path} lacks columns {sorted(missing)}")
        for line, row in enumerate(reader, start=2):
            if row["mode"] not in points:
                raise ValueError(f"{path} line {line}: mode must be one of {sorted(MODES)}, got {row['mode']!r}")
            try:
                points[row["mode"]][0].append(float(row["stretch"]))
                points[row["mode"]][1].append(float(row["nominal_stress_Pa"]))
            except ValueError:
                raise ValueError(f"{path} line {line}: stretch and nominal_stress_Pa must be numbers") from None
    (u_x, u_y), (s_x, s_y) = points["uniaxial"], points["pure_shear"]
    return OgdenTestData(np.array(u_x), np.array(u_y), np.array(s_x), np.array(s_y))


def write_test_data(data: OgdenTestData, path) -> Path:
    path = Path(path)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["mode", "stretch", "nominal_stress_Pa"])
        for mode, stretch, stress in (
            ("uniaxial", data.uniaxial_stretch, data.uniaxial_stress),
            ("pure_shear", data.shear_stretch, data.shear_stress),
        ):
            writer.writerows([mode, f"{x:.6g}", f"{y:.6g}"] for x, y in zip(stretch, stress))
    return path


def synthesize_test_data(
    mu,
    alpha,
    rng: np.random.Generator,
    *,
    uniaxial_range=(1.05, 3.0),
    shear_range=(1.05, 2.5),
    points: int = 25,
    relative_noise: float = 0.01,
) -> OgdenTestData:
    """Test curves of a known Ogden material with multiplicative Gaussian noise."""
    u_x = np.linspace(*uniaxial_range, points)
    s_x = np.linspace(*shear_range, points)
    noisy = lambda y: y * (1.0 + relative_noise * rng.standard_normal(y.shape))  # noqa: E731
    return OgdenTestData(
        u_x, noisy(uniaxial_nominal_stress(mu, alpha, u_x)), s_x, noisy(pure_shear_nominal_stress(mu, alpha, s_x))
    )


class _Objective:
    """Normalised residuals for a batch of parameter vectors x = (mu_1..mu_N [MPa], alpha_1..alpha_N)."""

    def __init__(self, data: OgdenTestData, n_terms: int):
        self.n_terms = n_terms
        self.data = data
        self.u_scale = np.max(np.abs(data.uniaxial_stress))
        self.s_scale = np.max(np.abs(data.shear_stress))
        self.evaluations = 0

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """x: (..., 2N) -> (..., points) residuals."""
        x = np.asarray(x, dtype=float)
        # Parameter batch (..., 1, N) against the test stretches (M,) gives stresses (..., M).
        mu = x[..., None, : self.n_terms] * STRESS_SCALE
        alpha = x[..., None, self.n_terms :]
        self.evaluations += int(np.prod(x.shape[:-1], dtype=int))
        d = self.data
        with np.errstate(over="ignore", invalid="ignore"):
            u = uniaxial_nominal_stress(mu, alpha, d.uniaxial_stretch)
            s = pure_shear_nominal_stress(mu, alpha, d.shear_stretch)
        return np.concatenate([(u - d.uniaxial_stress) / self.u_scale, (s - d.shear_stress) / self.s_scale], axis=-1)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """d residuals / d x for one parameter vector (analytic; points x 2N)."""
        mu, alpha = x[: self.n_terms] * STRESS_SCALE, x[self.n_terms :]
        blocks = []
        for stretch, scale, tail in (
            (self.data.uniaxial_stretch, self.u_scale, -0.5),  # uniaxial: second power -alpha/2 - 1
            (self.data.shear_stretch, self.s_scale, -1.0),  # pure shear: second power -alpha - 1
        ):
            lam, log = stretch[:, None], np.log(stretch)[:, None]
            head, rest = lam ** (alpha - 1.0), lam ** (tail * alpha - 1.0)
            d_mu = 2.0 / alpha * (head - rest) * STRESS_SCALE
            d_alpha = 2.0 * mu * (-(head - rest) / alpha**2 + (head - tail * rest) * log / alpha)
            blocks.append(np.hstack([d_mu, d_alpha]) / scale)
        return np.vstack(blocks)

    def cost(self, x: np.ndarray) -> np.ndarray:
        r = self.residuals(x)
        return np.where(np.all(np.isfinite(r), axis=-1), np.sum(r * r, axis=-1), np.inf)


def _bounds(n_terms: int, bounds: dict) -> tuple[np.ndarray, np.ndarray]:
    (mu_lo, mu_hi), (a_lo, a_hi) = bounds["mu"], bounds["alpha"]
    if not (mu_lo < mu_hi and a_lo < a_hi):
        raise ValueError(f"bounds must be (low, high) with low < high, got {bounds!r}")
    return np.array([mu_lo] * n_terms + [a_lo] * n_terms), np.array([mu_hi] * n_terms + [a_hi] * n_terms)


def _particle_swarm(objective: _Objective, low, high, rng, options: dict):
    particles = int(options.get("particles", 60))
    iterations = int(options.get("iterations", 600))
    chi, c = 0.7298, 1.49618  # Clerc-Kennedy constriction: convergent without velocity clamping
    position = rng.uniform(low, high, (particles, low.size))
    velocity = 0.1 * rng.uniform(low - high, high - low, position.shape)
    best_position, best_cost = position.copy(), objective.cost(position)
    for _ in range(iterations):
        leader = best_position[np.argmin(best_cost)]
        r1, r2 = rng.random(position.shape), rng.random(position.shape)
        velocity = chi * (velocity + c * r1 * (best_position - position) + c * r2 * (leader - position))
        position = np.clip(position + velocity, low, high)
        cost = objective.cost(position)
        improved = cost < best_cost
        best_position[improved], best_cost[improved] = position[improved], cost[improved]
    k = int(np.argmin(best_cost))
    return best_position[k], float(best_cost[k]), f"particle swarm: {particles} particles x {iterations} iterations"


def _multistart_least_squares(objective: _Objective, low, high, rng, options: dict):
    starts = int(options.get("starts", 4))
    max_nfev = int(options.get("max_nfev", 150))  # per start: a start that wanders is cut short
    best = None
    for start in rng.uniform(low, high, (starts, low.size)):
        fit = least_squares(objective.residuals, start, jac=objective.jacobian, bounds=(low, high),
                            x_scale="jac", max_nfev=max_nfev)
        if np.all(np.isfinite(fit.fun)) and (best is None or fit.cost < best.cost):
            best = fit
    if best is None:
        raise RuntimeError("no least-squares start converged to finite residuals")
    return best.x, float(2.0 * best.cost), f"multi-start least squares: best of {starts} starts ({best.message})"


METHODS = {"pso": _particle_swarm, "least_squares": _multistart_least_squares}


def fit_ogden(
    data: OgdenTestData,
    n_terms: int = 3,
    method: str = "least_squares",
    rng: np.random.Generator | None = None,
    options: dict | None = None,
) -> OgdenFitResult:
    """Fit an ``n_terms`` Ogden model to both test modes.

    options: ``bounds`` {"mu": (lo, hi) MPa, "alpha": (lo, hi)}; PSO: ``particles``, ``iterations``;
    least squares: ``starts``, ``max_nfev`` (per start). ``rng`` seeds the swarm or the starting
    points (default: seed 0).
    """
    if not isinstance(n_terms, int) or not 1 <= n_terms <= 6:
        raise ValueError(f"n_terms must be an integer 1..6, got {n_terms!r}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    options = dict(options or {})
    rng = np.random.default_rng(0) if rng is None else rng
    low, high = _bounds(n_terms, options.pop("bounds", DEFAULT_BOUNDS))
    objective = _Objective(data, n_terms)
    start = time.perf_counter()
    x, cost, message = METHODS[method](objective, low, high, rng, options)
    elapsed = time.perf_counter() - start
    return OgdenFitResult(
        mu=x[:n_terms] * STRESS_SCALE,
        alpha=x[n_terms:].copy(),
        cost=cost,
        success=bool(np.isfinite(cost)),
        message=message,
        method=method,
        n_evaluations=objective.evaluations,
        elapsed=elapsed,
    )
