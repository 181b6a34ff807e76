"""Ogden stress functions for incompressible films (paper eqs 4-7, with lambda_S in eq 7).

W = sum_i 2 mu_i / alpha_i**2 (l1**a_i + l2**a_i + l3**a_i - 3). The Ogden terms run along the last
axis of ``mu`` and ``alpha``; stretches broadcast against their leading axes, so a batch of
parameter sets of shape (P, 1, N) evaluated at stretches (M,) gives stresses (P, M).
"""
from __future__ import annotations

import numpy as np


def _sum_terms(mu, alpha, stretches, term):
    mu = np.asarray(mu, dtype=float)
    alpha = np.asarray(alpha, dtype=float)
    expanded = [np.asarray(s, dtype=float)[..., None] for s in stretches]
    return np.sum(term(mu, alpha, *expanded), axis=-1)


def uniaxial_nominal_stress(mu, alpha, stretch):
    """Eq 5: nominal (engineering) stress in uniaxial tension [Pa] at stretch lambda_U."""
    return _sum_terms(mu, alpha, (stretch,), lambda m, a, l: 2.0 * m / a * (l ** (a - 1.0) - l ** (-0.5 * a - 1.0)))


def pure_shear_nominal_stress(mu, alpha, stretch):
    """Eq 7 (with lambda_S): nominal stress in pure shear [Pa] at stretch lambda_S."""
    return _sum_terms(mu, alpha, (stretch,), lambda m, a, l: 2.0 * m / a * (l ** (a - 1.0) - l ** (-a - 1.0)))


def biaxial_cauchy_stress(mu, alpha, stretch_1, stretch_2):
    """True stress along direction 1 of a plane-stress film stretched (l1, l2), l3 = 1/(l1 l2) [Pa]."""
    return _sum_terms(mu, alpha, (stretch_1, stretch_2), lambda m, a, l1, l2: 2.0 * m / a * (l1**a - (l1 * l2) ** -a))


def biaxial_cauchy_stress_slope(mu, alpha, stretch_1, stretch_2):
    """d(sigma_1)/d(l1) at fixed l2 for :func:`biaxial_cauchy_stress` [Pa]."""
    # d(l3**a)/d(l1) = -a l3**a / l1 with l3 = 1 / (l1 l2)
    return _sum_terms(
        mu, alpha, (stretch_1, stretch_2), lambda m, a, l1, l2: 2.0 * m * (l1 ** (a - 1.0) + (l1 * l2) ** -a / l1)
    )
