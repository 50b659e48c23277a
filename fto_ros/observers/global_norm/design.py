"""The gains of Astolfi & Praly 2005 (eq. 79) and the default gain constants (footnote 6):
computed when the observer is built (adapter.py); nothing here runs per sample.

ROS-free.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import sympy


def gain_exprs(a: Sequence[sympy.Expr]) -> list[sympy.Expr]:
    """k = (I + L)^{-1} ((-a_1)^1, ..., (-a_m)^m) for the list a (eq. 79, forward substitution)."""
    m = len(a)
    k: list[sympy.Expr] = []
    for i in range(m):
        rhs = (-a[i]) ** (i + 1)
        for j in range(i):
            rhs -= (-a[i]) ** (i - j) * k[j]
        k.append(rhs)
    return k


def gains_numeric(a: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """(k, I + L) of eq. (79) for the numbers a."""
    m = len(a)
    IL = np.eye(m)
    for i in range(m):
        for j in range(i):
            IL[i, j] = (-a[i]) ** (i - j)
    v = np.array([(-a[i]) ** (i + 1) for i in range(m)])
    return np.linalg.solve(IL, v), IL


def default_c(dim: int) -> list[float]:
    """c_i for a_i = c_i gamma_hat (dim gains): the last 6 (footnote 6: > 11/2), the one before
    1.05 (2 (dim-1) 6^2 + 3.5), i.e. the necessary part of (61) with gamma_hat -> infinity
    (80 for dim = 2: a_0 > (2 c_1^2 + 3/2 + 2/gh^2) gh = 75.5 gh), earlier ones twice the sum
    of the later ones (frozen error matrix Hurwitz).  For dim >= 3 no constant c_0 satisfies
    (61) for all w (mu_0 grows like gamma_hat^2): the start-up check says so.
    """
    if dim == 1:
        return [6.0]
    c = [float(math.ceil(1.05 * (2 * (dim - 1) * 36.0 + 3.5))), 6.0]
    while len(c) < dim:
        c.insert(0, 2.0 * sum(c))
    return c
