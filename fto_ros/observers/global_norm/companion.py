"""Exact steps of x' = A x + r(t), A = S + c e0' (the upper shift plus a first column c),
compiled: what global_norm and high_gain integrate between two samples.

- ``companion_solve``: z with A z = b, O(m);
- ``companion_expm``: e^(A h), closed form for m <= 2; from the eigenvalues otherwise
  (Cardano and a Newton polish for m = 3, numpy's roots beyond), a Taylor series of the
  balanced matrix when |lambda| h < 1/2, the compiled scipy algorithm (core/linalg.py
  ``expm``) when eigenvalues cluster: stable and exact for ANY gain size (the gains of
  global_norm grow without bound);
- ``companion_step``: x(h) for r(t) a quadratic in t, exactly, from e^(A h);
- ``output_polynomial``: y between two samples (linear, or the quadratic through the last
  three); ``norm_estimator_step``: w' = -w + gamma_1, gamma_1 linear, exactly.

The arithmetic is the one of the Python code these replaced, in the same order: scalar
libm functions, CPython's complex arithmetic (``cpowi`` is CPython's integer power of a
complex, ``cexp`` its cmath.exp), so both paths agree bit for bit; numpy's roots (m >= 4)
and the clustered case (scipy's expm, compiled) may differ in the last bits.  Outputs go
into arrays the caller passes (no allocation for m <= 3).  ROS-free.
"""
from __future__ import annotations

import cmath
import math

import numpy as np

from ...core.jit import jit
from ...core.linalg import expm

#: cmath.exp computes exp(x - 1) e beyond this real part (CPython's CM_LOG_LARGE_DOUBLE)
_LOG_LARGE = math.log(1.7976931348623157e308 / 4.0)
_E = 2.7182818284590452354


def _cpowi_np(x, n):
    return x ** n


@jit(pure=_cpowi_np)
def cpowi(x, n):
    """x ** n for a complex x and an integer n, as CPython computes it (binary powers)."""
    m = n if n > 0 else -n
    r = complex(1.0, 0.0)
    p = x
    mask = 1
    while mask > 0 and m >= mask:
        if m & mask:
            r = r * p
        mask <<= 1
        p = p * p
    return r if n > 0 else complex(1.0, 0.0) / r


@jit(pure=cmath.exp)
def cexp(z):
    """cmath.exp of a finite z, as CPython computes it (an infinite result: the overflow
    CPython raises)."""
    if z.real > _LOG_LARGE:
        big = math.exp(z.real - 1.0)
        return complex(big * math.cos(z.imag) * _E, big * math.sin(z.imag) * _E)
    big = math.exp(z.real)
    return complex(big * math.cos(z.imag), big * math.sin(z.imag))


@jit
def companion_solve(c, b, z):
    """z with (S + c e0') z = b (z must not be b): rows i < m-1 read z_{i+1} + c_i z_0 = b_i."""
    m = c.shape[0]
    z0 = b[m - 1] / c[m - 1]
    z[0] = z0
    for i in range(m - 1):
        z[i + 1] = b[i] - c[i] * z0


def _roots_np(c):
    return np.array([complex(r) for r in np.roots([1.0] + [-float(v) for v in c])])


@jit(pure=_roots_np)
def _numpy_roots(c):
    m = c.shape[0]
    p = np.empty(m + 1)
    p[0] = 1.0
    for i in range(m):
        p[i + 1] = -c[i]
    return np.roots(p).astype(np.complex128)


@jit
def companion_char_roots(c, roots):
    """The roots of det(sI - A) = s^m - c0 s^(m-1) - ... - c_{m-1} into roots (complex)."""
    m = c.shape[0]
    if m != 3:
        roots[:] = _numpy_roots(c)
        return
    # float(): Python floats on the numpy path, so that the complex arithmetic is CPython's
    # (numpy's scalars would divide and raise complex numbers by other formulas)
    b = -float(c[0])
    cc = -float(c[1])
    d = -float(c[2])
    d0 = b * b - 3 * cc
    d1 = 2 * b ** 3.0 - 9 * b * cc + 27 * d
    sq = cmath.sqrt(complex(d1 * d1 - 4 * d0 ** 3.0, 0.0))
    big = (d1 + sq) if abs(d1 + sq) >= abs(d1 - sq) else (d1 - sq)
    if big == 0:
        for k in range(3):
            roots[k] = complex(-b / 3, 0.0)
        return
    C = (big / 2) ** (1.0 / 3.0)
    xi = complex(-0.5, math.sqrt(3) / 2)
    for k in range(3):
        Ck = C * cpowi(xi, k)
        lam = -(b + Ck + d0 / Ck) / 3
        for _ in range(2):                         # Newton polish
            p = ((lam + b) * lam + cc) * lam + d
            dp = (3 * lam + 2 * b) * lam + cc
            if dp == 0:
                break
            lam -= p / dp
        roots[k] = lam


@jit
def _closed_form_2(c, h, E):
    # A = [[c0, 1], [c1, 0]]: e^{Ah} = e^{mu h} (C I + S (A - mu I)), mu = c0/2
    mu = 0.5 * c[0]
    om2 = mu * mu + c[1]
    if om2 > 0:
        om = math.sqrt(om2)
        if om * h < 1.0:
            e = math.exp(mu * h)
            Cf = e * math.cosh(om * h)
            Sf = e * math.sinh(om * h) / om
        else:
            ep = math.exp((mu + om) * h)
            em = math.exp((mu - om) * h)
            Cf = 0.5 * (ep + em)
            Sf = 0.5 * (ep - em) / om
    elif om2 < 0:
        om = math.sqrt(-om2)
        e = math.exp(mu * h)
        Cf = e * math.cos(om * h)
        Sf = e * math.sin(om * h) / om
    else:
        e = math.exp(mu * h)
        Cf = e
        Sf = e * h
    E[0, 0] = Cf + Sf * (c[0] - mu)
    E[0, 1] = Sf
    E[1, 0] = Sf * c[1]
    E[1, 1] = Cf - Sf * mu


@jit
def _taylor(c, h, s, E, work):
    """exp(A h) by a 16-term Taylor series of the balanced matrix (||A h|| small: no
    cancellation of the spectral sum).  D^-1 A D = s (S + c_i / s^(i+1) e0'), D = diag(s^i);
    work: 2 m^2 floats."""
    m = c.shape[0]
    B = work[:m * m].reshape(m, m)
    T = work[m * m:2 * m * m].reshape(m, m)
    B[:, :] = 0.0
    sh = s * h
    for i in range(m):
        B[i, 0] += c[i] / s ** float(i + 1) * sh
        if i + 1 < m:
            B[i, i + 1] += sh
    for i in range(m):
        for j in range(m):
            E[i, j] = 1.0 if i == j else 0.0
    for k in range(16, 0, -1):                    # Horner: E = I + B/k E
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for l in range(m):
                    acc += B[i, l] * E[l, j]
                T[i, j] = (1.0 if i == j else 0.0) + acc / k
        E[:, :] = T
    for i in range(m):
        for j in range(m):
            E[i, j] = E[i, j] * s ** float(i - j)


@jit
def _spectral(c, h, roots, E, lpow):
    """exp(A h) = sum over the eigenvalues lam of e^(lam h) r l' / p'(lam) (right
    eigenvector r: r0 = 1, r_{i+1} = lam r_i - c_i; left l_j = lam^(m-1-j)); lpow: m complex."""
    m = c.shape[0]
    h = float(h)                   # Python floats and complex numbers on the numpy path
    E[:, :] = 0.0
    for q in range(m):
        lam = complex(roots[q])
        acc = complex(0.0, 0.0)
        for i in range(m - 1):
            acc = acc + (m - 1 - i) * float(c[i]) * cpowi(lam, m - 2 - i)
        dp = m * cpowi(lam, m - 1) - acc
        coef = cexp(lam * h) / dp
        for j in range(m):
            lpow[j] = cpowi(lam, m - 1 - j)
        r = complex(1.0, 0.0)
        for i in range(m):
            if i > 0:
                r = lam * r - float(c[i - 1])
            ri = coef * r
            for j in range(m):
                E[i, j] += (ri * complex(lpow[j])).real


@jit
def companion_expm(c, h, E, work, cwork):
    """E = exp((S + c e0') h) (m x m); work: 2 m^2 floats, cwork: 2 m complex."""
    m = c.shape[0]
    roots = cwork[:m]
    if m == 1:
        E[0, 0] = math.exp(c[0] * h)
        return
    if m == 2:
        _closed_form_2(c, h, E)
        return
    companion_char_roots(c, roots)
    scale = abs(roots[0])                         # max(...) or 1.0, as Python's
    for q in range(1, m):
        if abs(roots[q]) > scale:
            scale = abs(roots[q])
    if scale == 0.0:
        scale = 1.0
    if scale * h < 0.5:
        _taylor(c, h, scale, E, work)
        return
    sep = math.inf
    first = True
    finite = True
    for i in range(m):
        for j in range(i):
            v = abs(roots[i] - roots[j])
            if first or v < sep:
                sep = v
                first = False
        if not (math.isfinite(roots[i].real) and math.isfinite(roots[i].imag)):
            finite = False
    if sep < 1e-3 * scale or not finite:
        M = work[:m * m].reshape(m, m)
        for i in range(m):
            for j in range(m):
                a = (1.0 if j == i + 1 else 0.0) + (c[i] if j == 0 else 0.0)
                M[i, j] = a * h
        E[:, :] = expm(M)
        return
    _spectral(c, h, roots, E, cwork[m:2 * m])


@jit
def companion_step(c, E, x, h, r0, r1, r2, out, work):
    """out = x(h) for x' = (S + c e0') x + r0 + r1 t + r2 t^2, exactly, given E = exp(A h);
    work: 5 m floats.  Particular solution p(t) = P + Q t + R t^2: A R = -r2,
    A Q = 2 R - r1, A P = Q - r0."""
    m = c.shape[0]
    b = work[:m]
    R = work[m:2 * m]
    Q = work[2 * m:3 * m]
    P = work[3 * m:4 * m]
    d = work[4 * m:5 * m]
    for i in range(m):
        b[i] = -r2[i]
    companion_solve(c, b, R)
    for i in range(m):
        b[i] = 2.0 * R[i] - r1[i]
    companion_solve(c, b, Q)
    for i in range(m):
        b[i] = Q[i] - r0[i]
    companion_solve(c, b, P)
    for i in range(m):
        d[i] = x[i] - P[i]
    for i in range(m):
        acc = P[i] + (Q[i] + R[i] * h) * h
        for j in range(m):
            acc += E[i, j] * d[j]
        out[i] = acc


@jit
def gain_forcing(G, ya, yb, yc, v0, r0, r1, r2):
    """The forcing of x' = A x + G y(t) + e_n v under the output polynomial
    y = ya + yb s + yc s^2 (output_polynomial): r_q = G y_q, the model term v0 added to the
    last state's constant part (the shape companion_step takes)."""
    dim = G.shape[0]
    for i in range(dim):
        r0[i] = G[i] * ya
        r1[i] = G[i] * yb
        r2[i] = G[i] * yc
    r0[dim - 1] += v0


@jit
def output_polynomial(has_prev2, y_prev2, h_prev, y0, y1, h, quadratic):
    """(a, b, c) with y(s) = a + b s + c s^2 on [0, h] through y0, y1 (and y_prev2 at
    -h_prev when quadratic and has_prev2)."""
    s = (y1 - y0) / h
    if quadratic and has_prev2:
        kap = (y_prev2 - y0 + s * h_prev) / (h_prev * (h_prev + h))
        return y0, s - kap * h, kap
    return y0, s, 0.0


@jit
def norm_estimator_step(w0, g0, g1, h):
    """w(h) for w' = -w + gamma_1, gamma_1 linear from g0 to g1 over [0, h] (exact)."""
    em1 = -math.expm1(-h)                  # 1 - e^{-h}
    return (1.0 - em1) * w0 + g0 * em1 + (g1 - g0) * (h - em1) / h


# -- the Python side: lists in, lists out (the tests, design checks) ----------------------------
def expm_of(c, h: float) -> np.ndarray:
    """exp((S + c e0') h) for a sequence c (a new array)."""
    c = np.ascontiguousarray(c, dtype=float)
    m = c.size
    E = np.zeros((m, m))
    companion_expm(c, float(h), E, np.zeros(2 * m * m), np.zeros(2 * m, dtype=np.complex128))
    return E


def step_of(c, E, x, h: float, r0, r1, r2) -> np.ndarray:
    """x(h) of ``companion_step`` for sequences (a new array)."""
    def arr(v):
        return np.ascontiguousarray(v, dtype=float)
    c = arr(c)
    out = np.zeros(c.size)
    companion_step(c, np.ascontiguousarray(E, dtype=float), arr(x), float(h), arr(r0), arr(r1),
                   arr(r2), out, np.zeros(5 * c.size))
    return out
