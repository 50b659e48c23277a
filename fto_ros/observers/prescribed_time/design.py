"""The design quantities of Holloway & Krstic 2019 (IEEE TAC 64(9)): p_bar of the recursion
(18)-(21) and of Proposition 1, the gain polynomials (22)-(23) of Lemma 4, the bandwidth
factor that sets the sampling limit, and where the gains reach a cap.  Computed once, when
the observer is built (adapter.py); nothing here runs per sample.

ROS-free.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

#: largest plant order accepted (C's integer entries and the gain polynomials stay
#: far below 2^53 and double range there; tested up to n = 10, m = 20)
MAX_ORDER = 10
MAX_M = 20
#: the longest prescribed time (s) accepted: beyond ~1e10 s the window's model time no
#: longer counts whole microseconds exactly in a double (2^53 us)
MAX_T = 1e9
#: order from which the sampling guard is on by default, and its default value
GUARD_FROM_ORDER = 5
GUARD_DEFAULT = 0.1


def c_matrix(n: int, m: int) -> list[list[int]]:
    """The integers c_ij = p_bar_ij T^(i-j) of the recursion (18)-(21), 0-based rows/cols.

    Remark 1's algorithm: row n from (21) backwards, then rows n-1, ..., 2 from
    (20) backwards, each forced by the row below.  p_bar_ij = c_ij / T^(i-j).
    """
    C = [[0] * n for _ in range(n)]
    for i in range(n):
        C[i][i] = 1                                        # (18); (19): zeros above
    for j in range(n, 1, -1):                              # (21), paper's 1-based j
        C[n - 1][j - 2] = -(2 * n + m - j) * C[n - 1][j - 1]
    for i in range(n - 1, 1, -1):                          # (20), paper's 1-based i
        for j in range(i, 1, -1):
            C[i - 1][j - 2] = -(n + m + i - j) * C[i - 1][j - 1] + C[i][j - 1]
    return C


def p_bar(n: int, m: int, T: float) -> np.ndarray:
    """p_bar_ij (1 <= j <= i <= n) of (18)-(21) as an n x n lower-triangular array."""
    C = np.array(c_matrix(n, m), dtype=float)
    i = np.arange(n)
    expo = np.maximum(i[:, None] - i[None, :], 0)
    return np.tril(C / float(T) ** expo)


def p_bar_closed_form(n: int, m: int, T) -> list[list]:
    """p_bar from Proposition 1 (eq. 28 and the sum formula), exact if T is a Fraction.

    Row n in closed form, rows n-1..1 from the row below (the formula's forcing).
    """
    T = Fraction(T) if not isinstance(T, Fraction) else T
    f = math.factorial
    p = [[Fraction(0)] * (n + 1) for _ in range(n + 2)]    # 1-based, p[n+1][.] = 0
    for i in range(1, n + 1):
        p[i][i] = Fraction(1)
    for j in range(1, n):
        p[n][j] = Fraction((-1) ** (n - j) * f(2 * n + m - j - 1), f(n + m - 1)) / T ** (n - j)
    for i in range(n - 1, 0, -1):
        for j in range(1, i):
            k = i - j
            val = Fraction((-1) ** k * f(n + m + k - 1), f(n + m - 1)) / T ** k
            for l in range(k):
                val += (Fraction((-1) ** (k - l - 1) * f(n + m + k - 1), f(n + m + l))
                        / T ** (k - l - 1) * p[i + 1][i - l])
            p[i][j] = val
    return [row[1:n + 1] for row in p[1:n + 1]]


def gain_coefficients(n: int, m: int, T: float, l) -> np.ndarray:
    """h_bar of Lemma 4: g_i(mu_1) = sum_k h_bar[i-1, k] mu_1^k, an n x (n+1) array.

    Polynomial form of (22)-(23), in the order i = 1, ..., n.
    """
    pb = p_bar(n, m, T)
    H = np.zeros((n, n + 1))
    for i in range(1, n + 1):
        g = np.zeros(n + 1)
        g[0] = l[i - 1]
        if i < n:
            g[i] += (n + m + i - 1) / T * pb[i - 1, 0] - pb[i, 0]       # (22)
        else:
            g[n] += (2 * n + m - 1) / T * pb[n - 1, 0]                  # (23)
        for j in range(1, i):
            # - g_j(mu) p_bar_ij mu^(i-j): shift g_j's coefficients up by i - j
            g[i - j:] -= pb[i - 1, j - 1] * H[j - 1, :n + 1 - (i - j)]
        H[i - 1] = g
    return H


def inverse_unit_lower(C: list[list[int]]) -> np.ndarray:
    """Exact inverse of a unit lower-triangular integer matrix (integers again)."""
    n = len(C)
    X = [[0] * n for _ in range(n)]
    for j in range(n):
        X[j][j] = 1
        for i in range(j + 1, n):
            X[i][j] = -sum(C[i][k] * X[k][j] for k in range(j, i))
    return np.array(X, dtype=float)


def hurwitz_roots(coeffs) -> np.ndarray:
    """Roots of s^n + c_1 s^(n-1) + ... + c_n."""
    return np.roots(np.concatenate(([1.0], np.asarray(coeffs, dtype=float))))


def is_hurwitz(coeffs) -> bool:
    """Whether every root of s^n + c_1 s^(n-1) + ... + c_n has a negative real part."""
    return bool(np.all(hurwitz_roots(coeffs).real < 0))


def bandwidth_factor(n: int, m: int) -> float:
    """rho_nm: the observer's bandwidth is about rho_nm / (T - s) late in a window.

    Largest |root| of s^n + c_1 s^(n-1) + ... + c_n with c_i = h_bar_ii T^i, the
    leading coefficients of the gains (T-free); those dominate as mu_1 grows.
    """
    H = gain_coefficients(n, m, 1.0, np.zeros(n))
    return float(np.max(np.abs(hurwitz_roots([H[i, i + 1] for i in range(n)]))))


def mu_at_gain(Hg: np.ndarray, g_max: float) -> float:
    """Smallest mu_1 >= 1 at which some |g_i(mu_1)| reaches g_max (inf if never); Hg the
    gain coefficients (gain_coefficients)."""
    best = math.inf
    for i in range(Hg.shape[0]):
        for sign in (1.0, -1.0):
            c = Hg[i, :i + 2].copy()          # g_(i+1) has degree i + 1
            c[0] -= sign * g_max
            c = np.trim_zeros(c, "b")
            if c.size < 2:
                continue
            for z in np.roots(c[::-1]):
                if abs(z.imag) <= 1e-9 * max(1.0, abs(z)) and z.real >= 1.0:
                    best = min(best, float(z.real))
    return best
