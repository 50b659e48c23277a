"""The windowed momentum estimator's numerics on the actual sample instants, compiled
(``core.jit``; with numba off the same code runs as Python): the quadrature weights of the
window's kernel on non-uniform nodes, the centred velocity of a sample, the window's sum.
docs/external_torque.md derives them; the kernel (observers/external_torque/kernel.py) calls
them with slices of its own arrays (no allocation).

**The kernel.** kappa(s) = 30 s^2 (1 - s)^2 on [0, 1] (integral 1; kappa and kappa' vanish at
both ends), k(u) = kappa(u / T) / T on a window of length T, K(s) = 10 s^3 - 15 s^4 + 6 s^5
its integral.

**The weights.** The window's W + 1 nodes u_0 = 0 < u_1 < ... < u_W = T are the ages of the
samples it holds (u_j = t_newest - t_j; T = u_W: the window is its W + 1 newest samples,
wherever they fell). A smooth factor g (M q~, Mdot q~, q~, phi) is interpolated on each
interval [u_i, u_i+1] by the cubic through the four nodes around it (i-1 .. i+2, shifted
inside at the ends), and the product with the kernel's k'', k' or k (polynomials) is
integrated exactly, by 4-point Gauss-Legendre on each interval (exact to degree 7: a cubic
times kappa, a quartic): A_j, B_j, C_j are the weights of g(u_j) in the integrals of
k'' g, k' g, k g. The rule is exact whenever g is a cubic on every four neighbouring
nodes, on any node spacing. The torque, held between samples, is integrated exactly:
D_j = K(u_j+1 / T) - K(u_j / T) is the weight of the torque held over [u_j, u_j+1], the one
of sample j + 1.
"""
from __future__ import annotations

import math

from ..core.jit import jit

#: 4-point Gauss-Legendre nodes and weights on [-1, 1]
_GL_X = (-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526)
_GL_W = (0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538)


@jit
def kappa(s, derivative):
    """kappa(s) (derivative 0), kappa', kappa'' (1, 2), or its integral K(s) (-1)."""
    if derivative == -1:
        return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))
    if derivative == 0:
        return 30.0 * s * s * (1.0 - s) * (1.0 - s)
    if derivative == 1:
        return s * (60.0 + s * (-180.0 + 120.0 * s))
    return 60.0 + s * (-360.0 + 360.0 * s)


@jit
def weights(u, W, A, B, C, D):
    """A, B, C (W + 1) and D (W) for the nodes u[0..W] (increasing, u[0] = 0); see the
    module doc. Returns ||A||_2 (the noise gain of the momentum term per unit of the
    positions' noise)."""
    T = u[W]
    for j in range(W + 1):
        A[j] = 0.0
        B[j] = 0.0
        C[j] = 0.0
    for i in range(W):
        p = i - 1
        if p < 0:
            p = 0
        if p > W - 3:
            p = W - 3
        a, b = u[i], u[i + 1]
        mid, half = 0.5 * (a + b), 0.5 * (b - a)
        x0, x1, x2, x3 = u[p], u[p + 1], u[p + 2], u[p + 3]
        d0 = (x0 - x1) * (x0 - x2) * (x0 - x3)
        d1 = (x1 - x0) * (x1 - x2) * (x1 - x3)
        d2 = (x2 - x0) * (x2 - x1) * (x2 - x3)
        d3 = (x3 - x0) * (x3 - x1) * (x3 - x2)
        for g in range(4):
            x = mid + half * _GL_X[g]
            wg = half * _GL_W[g]
            s = x / T
            k0 = wg * kappa(s, 0) / T
            k1 = wg * kappa(s, 1) / (T * T)
            k2 = wg * kappa(s, 2) / (T * T * T)
            l0 = (x - x1) * (x - x2) * (x - x3) / d0
            l1 = (x - x0) * (x - x2) * (x - x3) / d1
            l2 = (x - x0) * (x - x1) * (x - x3) / d2
            l3 = (x - x0) * (x - x1) * (x - x2) / d3
            A[p] += k2 * l0
            A[p + 1] += k2 * l1
            A[p + 2] += k2 * l2
            A[p + 3] += k2 * l3
            B[p] += k1 * l0
            B[p + 1] += k1 * l1
            B[p + 2] += k1 * l2
            B[p + 3] += k1 * l3
            C[p] += k0 * l0
            C[p + 1] += k0 * l1
            C[p + 2] += k0 * l2
            C[p + 3] += k0 * l3
        D[i] = kappa(b / T, -1) - kappa(a / T, -1)
    acc = 0.0
    for j in range(W + 1):
        acc += A[j] * A[j]
    return math.sqrt(acc)


@jit
def slope(t, q, first, count, n, out):
    """out[i] = the least-squares slope of q[first + l, i] over t[first + l], l < count
    (the centred velocity of the middle sample when count = 2 m + 1)."""
    tm = 0.0
    for l in range(count):
        tm += t[first + l]
    tm /= count
    den = 0.0
    for l in range(count):
        d = t[first + l] - tm
        den += d * d
    for i in range(n):
        qm = 0.0
        for l in range(count):
            qm += q[first + l, i]
        qm /= count
        acc = 0.0
        for l in range(count):
            acc += (t[first + l] - tm) * (q[first + l, i] - qm)
        out[i] = acc / den


@jit
def push_history(st, oh, ohq, n, s, q):
    """The stamp s and positions q into a five-sample history held in st (stamps at oh,
    positions at ohq, n per sample; oldest first): what extrapolation_residual reads."""
    for l in range(4):
        st[oh + l] = st[oh + l + 1]
        for i in range(n):
            st[ohq + l * n + i] = st[ohq + (l + 1) * n + i]
    st[oh + 4] = s
    for i in range(n):
        st[ohq + 4 * n + i] = q[i]


@jit
def extrapolation_residual(t, q, n, out):
    """Per joint, the residual of the cubic extrapolation of q[4] at t[4] from the samples
    0..3, over sqrt(1 + sum of its coefficients squared): white position noise of standard
    deviation sigma gives residuals of standard deviation sigma (a smooth motion adds
    |q''''| times the product of the four intervals / 24, about 1e-12 rad at 1 kHz)."""
    x = t[4]
    norm = 1.0
    c0 = (x - t[1]) * (x - t[2]) * (x - t[3]) / ((t[0] - t[1]) * (t[0] - t[2]) * (t[0] - t[3]))
    c1 = (x - t[0]) * (x - t[2]) * (x - t[3]) / ((t[1] - t[0]) * (t[1] - t[2]) * (t[1] - t[3]))
    c2 = (x - t[0]) * (x - t[1]) * (x - t[3]) / ((t[2] - t[0]) * (t[2] - t[1]) * (t[2] - t[3]))
    c3 = (x - t[0]) * (x - t[1]) * (x - t[2]) / ((t[3] - t[0]) * (t[3] - t[1]) * (t[3] - t[2]))
    norm = math.sqrt(1.0 + c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3)
    for i in range(n):
        out[i] = (q[4, i] - c0 * q[0, i] - c1 * q[1, i] - c2 * q[2, i] - c3 * q[3, i]) / norm
