"""Ogden stress functions for incompressible films (paper eqs 4-7, with lambda_S in eq 7).

All functions broadcast over numpy arrays of stretches; ``mu`` and ``alpha`` are 1-D sequences of
the Ogden constants (W = sum 2 mu_i / alpha_i**2 (l1**a_i + l2**a_i + l3**a_i - 3)).
"""
from __future__ import annotations

import numpy as np


def _sum_terms(mu, alpha, stretch_shape, term):
    """sum_i term(mu_i, alpha_i), with the Ogden terms on a leading axis broadcast over the stretches."""
    shape = (-1,) + (1,) * len(stretch_shape)
    mu_c = np.asarray(mu, dtype=float).reshape(shape)
    alpha_c = np.asarray(alpha, dtype=float).reshape(shape)
    return np.sum(term(mu_c, alpha_c), axis=0)


def uniaxial_nominal_stress(mu, alpha, stretch):
    """Eq 5: nominal (engineering) stress in uniaxial tension [Pa] at stretch lambda_U."""
    lam = np.asarray(stretch, dtype=float)
    return _sum_terms(
        mu, alpha, lam.shape, lambda m, a: 2.0 * m / a * (lam ** (a - 1.0) - lam ** (-0.5 * a - 1.0))
    )


def pure_shear_nominal_stress(mu, alpha, stretch):
    """Eq 7 (with lambda_S): nominal stress in pure shear [Pa] at stretch lambda_S."""
    lam = np.asarray(stretch, dtype=float)
    return _sum_terms(mu, alpha, lam.shape, lambda m, a: 2.0 * m / a * (lam ** (a - 1.0) - lam ** (-a - 1.0)))


def biaxial_cauchy_stress(mu, alpha, stretch_1, stretch_2):
    """True stress along direction 1 of a plane-stress film stretched (l1, l2), l3 = 1/(l1 l2) [Pa]."""
    l1 = np.asarray(stretch_1, dtype=float)
    l3 = 1.0 / (l1 * np.asarray(stretch_2, dtype=float))
    shape = np.broadcast_shapes(l1.shape, l3.shape)
    return _sum_terms(mu, alpha, shape, lambda m, a: 2.0 * m / a * (l1**a - l3**a))


def biaxial_cauchy_stress_slope(mu, alpha, stretch_1, stretch_2):
    """d(sigma_1)/d(l1) at fixed l2 for :func:`biaxial_cauchy_stress` [Pa]."""
    l1 = np.asarray(stretch_1, dtype=float)
    l3 = 1.0 / (l1 * np.asarray(stretch_2, dtype=float))
    shape = np.broadcast_shapes(l1.shape, l3.shape)
    # d(l3**a)/d(l1) = -a l3**a / l1
    return _sum_terms(mu, alpha, shape, lambda m, a: 2.0 * m * (l1 ** (a - 1.0) + l3**a / l1))
