"""Small dense linear algebra for the per-sample kernels (numba-compiled, see core/jit.py).

The observers' matrices have a few rows; what costs is calling into a library, not the
flops.  These loops compile to straight machine code inside a kernel; without numba the
``pure`` twins run numpy (the same results up to the order of a sum).

- ``matvec(A, x, out)``: out = A x (A C-contiguous 2-D) through BLAS, no allocation.
- ``expm(A)``: e^A compiled (below: the algorithm scipy uses), for exponentials needed at
  every sample (the EKF); ``expm_exact(A)``: scipy's own, for what is computed once and
  cached (step matrices), so cached steps are bit for bit the ones of the numpy path.
- ``solve(A, b, out)`` / ``inv``: Gaussian elimination with partial pivoting; they report a
  singular or non-finite matrix instead of raising.
"""
from __future__ import annotations

import math

import numpy as np

from scipy.linalg import expm as _scipy_expm

from . import jit as J
from .jit import jit, numba


@jit
def matvec(A, x, out):
    """out = A x through BLAS (dgemv), as numpy's ``A @ x`` does: the same order of the sums
    (bit for bit where numpy's and scipy's BLAS builds agree), no allocation.  A one-row A
    is a dot product (ddot), as numpy computes it: a compiled dgemv of one row sums in
    another order (measured: 1 in 4 random 1 x 3 products differ in the last bit)."""
    if A.shape[0] == 1:
        out[0] = np.dot(A[0], x)
    else:
        np.dot(A, x, out)


@jit
def norm(v):
    """The 2-norm as numpy.linalg.norm computes it (sqrt of the dot product)."""
    return math.sqrt(np.dot(v, v))


@jit
def finite(v):
    """Whether every element of the 1-D array v is finite."""
    acc = 0.0
    for i in range(v.shape[0]):
        acc += v[i] * 0.0
    return acc == 0.0


# -- the matrix exponential --------------------------------------------------------------
# Scaling and squaring with Pade approximants of degree 3, 5, 7, 9 or 13, the degree and
# the scaling chosen as Al-Mohy & Higham 2009 ("A new scaling and squaring algorithm for the
# matrix exponential", SIAM J. Matrix Anal. Appl. 31(3), Algorithm 5.1: the norms of A^4,
# A^6, A^8, A^10 and the backward-error bound from the 1-norm of |A|^(2m+1)), with the
# triangular case's exact diagonal and superdiagonal at each squaring (their Code Fragment
# 2.1), the same choices and the same order of operations scipy.linalg.expm makes (its
# constants: theta_13 = 4.25 and the coefficients below), so the two agree to the order of
# the sums inside a matrix product.
_THETA = np.array([1.495585217958292e-2, 2.539398330063230e-1, 9.504178996162932e-1,
                   2.097847961257068e0, 4.25])
_U = 2.0 ** -53
_COEFF = np.array([100800.0, 10059033600.0, 4487938430976000.0, 5914384781877411840000.0,
                   113250775606021113483283660800000000.0]) * _U
_B = np.array([64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
               1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
               33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0])
_B3 = np.array([120.0, 60.0, 12.0])
_B5 = np.array([30240.0, 15120.0, 3360.0, 420.0, 30.0])
_B7 = np.array([17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0])
_B9 = np.array([17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0,
                2162160.0, 110880.0, 3960.0, 90.0])


@jit
def _norm1(A):
    """max column sum of |A| (nan if any is nan)."""
    n = A.shape[0]
    best = 0.0
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += abs(A[i, j])
        if s > best or s != s:
            best = s
    return best


@jit
def _spin(v, absA, times):
    """v <- v |A|^times (row vector: 1-norm powers of |A|)."""
    for _ in range(times):
        v = v @ absA
    return v


@jit
def _lm(v, normA, coeff, m2):
    x = v.max() / normA / coeff
    if not x > 0.0:
        return 0
    return max(int(math.ceil(math.log2(x) / m2)), 0)


@jit
def _pick(A, A2, A4, A6):
    """(m, s): the Pade degree and the scaling 2^-s."""
    n = A.shape[0]
    absA = np.abs(A)
    v = np.ones(n) @ absA
    normA = v.max()
    d4 = _norm1(A4) ** 0.25
    d6 = _norm1(A6) ** (1.0 / 6.0)
    eta = max(d4, d6)
    v = _spin(v, absA, 6)
    if eta < _THETA[0] and _lm(v, normA, _COEFF[0], 6) == 0:
        return 3, 0
    v = _spin(v, absA, 4)
    if eta < _THETA[1] and _lm(v, normA, _COEFF[1], 10) == 0:
        return 5, 0
    A8 = A4 @ A4
    d8 = _norm1(A8) ** 0.125
    eta2 = max(d6, d8)
    v = _spin(v, absA, 4)
    if eta2 < _THETA[2] and _lm(v, normA, _COEFF[2], 14) == 0:
        return 7, 0
    v = _spin(v, absA, 4)
    if eta2 < _THETA[3] and _lm(v, normA, _COEFF[3], 18) == 0:
        return 9, 0
    d10 = _norm1(A6 @ A4) ** 0.1
    eta4 = min(eta2, max(d8, d10))
    s = max(int(math.ceil(math.log2(eta4 / _THETA[4]))), 0) if eta4 > 0.0 else 0
    if s != 0:
        absA = absA * 2.0 ** (-s)
        v = v * 2.0 ** (-s * 19.0)
        normA = normA * 2.0 ** (-s)
    v = _spin(v, absA, 8)
    return 13, s + _lm(v, normA, _COEFF[4], 26)


@jit
def _add_diag(M, c):
    for i in range(M.shape[0]):
        M[i, i] += c


@jit
def _pade(A, A2, A4, A6, m):
    """r_m(A) = I + 2 (V - U)^-1 U."""
    if m == 3:
        U = A @ A2 + _B3[1] * A
        V = _B3[2] * A2
        _add_diag(V, _B3[0])
    elif m == 5:
        W = _B5[3] * A2 + A4
        _add_diag(W, _B5[1])
        U = A @ W
        V = _B5[2] * A2 + _B5[4] * A4
        _add_diag(V, _B5[0])
    elif m == 7:
        W = _B7[3] * A2 + _B7[5] * A4 + A6
        _add_diag(W, _B7[1])
        V = _B7[2] * A2 + _B7[4] * A4 + _B7[6] * A6
        _add_diag(V, _B7[0])
        U = A @ W
    elif m == 9:
        A8 = A4 @ A4
        W = _B9[3] * A2 + _B9[5] * A4 + _B9[7] * A6 + A8
        _add_diag(W, _B9[1])
        V = _B9[2] * A2 + _B9[4] * A4 + _B9[6] * A6 + _B9[8] * A8
        _add_diag(V, _B9[0])
        U = A @ W
    else:
        W2 = _B[9] * A2 + _B[11] * A4 + _B[13] * A6
        W3 = _B[2] * A2 + _B[4] * A4 + _B[6] * A6
        W4 = _B[8] * A2 + _B[10] * A4 + _B[12] * A6
        W1 = _B[3] * A2 + _B[5] * A4 + _B[7] * A6
        _add_diag(W1, _B[1])
        _add_diag(W3, _B[0])
        U = A @ (A6 @ W2 + W1)
        V = A6 @ W4 + W3
    X = np.linalg.solve(V - U, U)
    R = 2.0 * X
    _add_diag(R, 1.0)
    return R


@jit
def _exp_sinch_super(d, sd, scale, out, upper):
    """The exact (super or sub) diagonal of e^(scale T), T triangular with diagonal d."""
    n = d.shape[0]
    for i in range(n - 1):
        a = d[i] * scale
        b = d[i + 1] * scale
        if b - a == 0.0:
            f = math.exp(a)
        else:
            f = (math.exp(b) - math.exp(a)) / (b - a)
        if upper:
            out[i, i + 1] = f * (sd[i] * scale)
        else:
            out[i + 1, i] = f * (sd[i] * scale)


def _expm_np(A):
    return np.ascontiguousarray(_scipy_expm(A))


def _expm_exact_jit(A):
    with numba.objmode(out="float64[:, ::1]"):
        out = _expm_np(A)
    return out


#: e^A computed by scipy.linalg.expm itself (from compiled code through numba's object mode,
#: about 2 us plus scipy's time): where a result is cached and reused (the step caches), so
#: that the compiled kernels step with exactly the matrices the Python code used
expm_exact = _expm_np if not J.ENABLED else J.jit(_expm_exact_jit, gil=True)


@jit(pure=_expm_np)
def expm(A):
    """e^A (a new array); nan everywhere for a non-finite A."""
    n = A.shape[0]
    A = np.ascontiguousarray(A)
    if not _norm1(A) < math.inf:
        return np.full((n, n), np.nan)
    lower = False
    upper = False
    for i in range(n):
        for j in range(n):
            if A[i, j] != 0.0:
                if i > j:
                    lower = True
                elif j > i:
                    upper = True
    R = np.zeros((n, n))
    if not lower and not upper:               # diagonal
        for i in range(n):
            R[i, i] = math.exp(A[i, i])
        return R
    A2 = A @ A
    A4 = A2 @ A2
    A6 = A4 @ A2
    m, s = _pick(A, A2, A4, A6)
    if s != 0:
        f = 2.0 ** (-s)
        R = _pade(A * f, A2 * f ** 2, A4 * f ** 4, A6 * f ** 6, m)
    else:
        R = _pade(A, A2, A4, A6, m)
    triangular = not lower or not upper
    if s != 0:
        if triangular:
            d = np.empty(n)
            sd = np.empty(max(n - 1, 0))
            for i in range(n):
                d[i] = A[i, i]
            for i in range(n - 1):
                sd[i] = A[i, i + 1] if upper else A[i + 1, i]
            for i in range(n):
                R[i, i] = math.exp(d[i] * 2.0 ** (-s))
            for k in range(s - 1, -1, -1):
                R = R @ R
                sc = 2.0 ** (-k)
                for i in range(n):
                    R[i, i] = math.exp(d[i] * sc)
                _exp_sinch_super(d, sd, sc, R, upper)
        else:
            for _ in range(s):
                R = R @ R
    if triangular:
        for i in range(n):
            for j in range(n):
                if (upper and i > j) or (lower and j > i):
                    R[i, j] = 0.0
    return R


def _solve_np(A, b, out):
    try:
        out[:] = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return False
    return bool(np.isfinite(out).all())


@jit(pure=_solve_np)
def solve(A, b, out):
    """out = A^-1 b by Gaussian elimination with partial pivoting (A, b unchanged);
    False when A is singular or a value is not finite."""
    n = A.shape[0]
    M = A.copy()
    x = b.copy()
    for c in range(n):
        p = c
        big = abs(M[c, c])
        for r in range(c + 1, n):
            if abs(M[r, c]) > big:
                big = abs(M[r, c])
                p = r
        if not big > 0.0 or not big < math.inf:
            return False
        if p != c:
            for j in range(n):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            x[c], x[p] = x[p], x[c]
        piv = M[c, c]
        for r in range(c + 1, n):
            f = M[r, c] / piv
            if f != 0.0:
                for j in range(c, n):
                    M[r, j] -= f * M[c, j]
                x[r] -= f * x[c]
    for c in range(n - 1, -1, -1):
        acc = x[c]
        for j in range(c + 1, n):
            acc -= M[c, j] * out[j]
        out[c] = acc / M[c, c]
    return finite(out)
