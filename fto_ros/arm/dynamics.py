"""An arm's rigid-body dynamics over the packed tree of :mod:`.tree`, compiled (``core.jit``;
with numba off the same code runs as plain Python): Featherstone's recursive algorithms
(Rigid Body Dynamics Algorithms, 2008: the composite-rigid-body algorithm for M(q), the
recursive Newton-Euler algorithm for inverse dynamics and the bias), written in the world
frame: every spatial vector in the root's axes at the root's origin, so a body's motion
subspace S_i, velocity v_i and inertia I_i need no transform between bodies.

Spatial algebra (motion m = (w; u), force f = (n; f), Featherstone's order):

    m1 x m2  = (w1 x w2; w1 x u2 + u1 x w2)          m x* f = (w x n + u x f; w x f)
    I m      = (I_O w + h x u; m u - h x w)           (10 parameters: m, h = m c, I_O)
    d/dt I_i = v_i x* I_i - I_i v_i x
             = (0, w x h + m u, [w] I_O - I_O [w] + 2 (u.h) 1 - h u' - u h')
    S_i' = v_i x S_i  (S_i is fixed in body i)

- M_ij = S_i' Ic_j S_j for i an ancestor of j (or i = j), Ic_j the composite inertia of j's
  subtree (CRBA in the world frame), plus the armature on the diagonal;
- inverse dynamics (RNEA): a_i = a_parent + S_i qdd_i + (v_i x S_i) qd_i, a_root = -gravity,
  f_i = I_i a_i + v_i x* I_i v_i, tau_i = S_i' (sum of f over i's subtree);
- g(q) = S_i' Ic_i a_g (a_g = (0; 0, 0, 9.81)); C(q, v) v: the RNEA with no gravity and
  qdd = 0;
- Mdot = dM/dt along v: d/dt (S_i' Ic_j S_j) = S_i' (Icdot_j S_j + Ic_j (v_j x S_j) - v_i x* F_j)
  = S_i' (Icdot_j S_j + Ic_j (v_j x S_j)) + (v_i x S_i)' F_j, F_j = Ic_j S_j, Icdot_j the sum
  of d/dt I_l over j's subtree;
- the Christoffel C (Mdot = C + C'): C = (Mdot + P - P') / 2, P = d(M(q) v)/dq at fixed v,
  P_dk = F_d . (v_parent(k) x S_k) for k an ancestor of d or d itself, P_kd = S_k . (S_d x* H_d +
  Ic_d (v_parent(d) x S_d)) for k a strict ancestor of d, H_d the momentum of d's subtree
  (from (M v)_i = S_i' H_i, S_i and H_i moving with the joints above);
- a frame's Jacobian: columns (u_i + w_i x o; w_i) for the joints above the frame, o its origin.

Every quantity is computed for every moving body (the full tree: listed, passive and mimic
joints) and reduced to the listed joints through the coordinate map of :mod:`.tree`
(v_full = G v): M = G' M_full G, tau = G' tau_full, C = G' C_full G, J = J_full G. The
entry points take (rows, n, q, passive, ...) and return new arrays.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.jit import jit
from .tree import ACTIVE, ARMATURE, AXIS, INERTIA, MULT, OFFSET, PARENT, PASSIVE, POS, ROT, TYPE

#: gravitational acceleration, m/s^2, along -z of the root frame
GRAVITY = 9.81


# -- spatial algebra on 6-vectors and 10 inertia parameters ------------------------------------
@jit
def _dot6(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]


@jit
def _cross_motion(a, b, out):
    """out = a x b (motion vectors)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    out[3] = a[1] * b[5] - a[2] * b[4] + a[4] * b[2] - a[5] * b[1]
    out[4] = a[2] * b[3] - a[0] * b[5] + a[5] * b[0] - a[3] * b[2]
    out[5] = a[0] * b[4] - a[1] * b[3] + a[3] * b[1] - a[4] * b[0]


@jit
def _cross_force(a, f, out):
    """out = a x* f (a motion, f a force)."""
    out[0] = a[1] * f[2] - a[2] * f[1] + a[4] * f[5] - a[5] * f[4]
    out[1] = a[2] * f[0] - a[0] * f[2] + a[5] * f[3] - a[3] * f[5]
    out[2] = a[0] * f[1] - a[1] * f[0] + a[3] * f[4] - a[4] * f[3]
    out[3] = a[1] * f[5] - a[2] * f[4]
    out[4] = a[2] * f[3] - a[0] * f[5]
    out[5] = a[0] * f[4] - a[1] * f[3]


@jit
def _inertia_times(I, s, out):
    """out = I s (I: m, hx, hy, hz, Ixx, Iyy, Izz, Iyz, Ixz, Ixy; s a motion)."""
    m, hx, hy, hz = I[0], I[1], I[2], I[3]
    w0, w1, w2, u0, u1, u2 = s[0], s[1], s[2], s[3], s[4], s[5]
    out[0] = I[4] * w0 + I[9] * w1 + I[8] * w2 + hy * u2 - hz * u1
    out[1] = I[9] * w0 + I[5] * w1 + I[7] * w2 + hz * u0 - hx * u2
    out[2] = I[8] * w0 + I[7] * w1 + I[6] * w2 + hx * u1 - hy * u0
    out[3] = m * u0 - (hy * w2 - hz * w1)
    out[4] = m * u1 - (hz * w0 - hx * w2)
    out[5] = m * u2 - (hx * w1 - hy * w0)


@jit
def _inertia_rate(I, v, out):
    """out = the parameters of v x* I - I v x (the rate of a body's world inertia)."""
    hx, hy, hz, m = I[1], I[2], I[3], I[0]
    w0, w1, w2, u0, u1, u2 = v[0], v[1], v[2], v[3], v[4], v[5]
    xx, yy, zz, yz, xz, xy = I[4], I[5], I[6], I[7], I[8], I[9]
    # A = [w] I_O
    a00 = -w2 * xy + w1 * xz
    a01 = -w2 * yy + w1 * yz
    a02 = -w2 * yz + w1 * zz
    a10 = w2 * xx - w0 * xz
    a11 = w2 * xy - w0 * yz
    a12 = w2 * xz - w0 * zz
    a20 = -w1 * xx + w0 * xy
    a21 = -w1 * xy + w0 * yy
    a22 = -w1 * xz + w0 * yz
    uh = u0 * hx + u1 * hy + u2 * hz
    out[0] = 0.0
    out[1] = w1 * hz - w2 * hy + m * u0
    out[2] = w2 * hx - w0 * hz + m * u1
    out[3] = w0 * hy - w1 * hx + m * u2
    out[4] = 2.0 * a00 + 2.0 * uh - 2.0 * hx * u0
    out[5] = 2.0 * a11 + 2.0 * uh - 2.0 * hy * u1
    out[6] = 2.0 * a22 + 2.0 * uh - 2.0 * hz * u2
    out[7] = a12 + a21 - hy * u2 - u1 * hz
    out[8] = a02 + a20 - hx * u2 - u0 * hz
    out[9] = a01 + a10 - hx * u1 - u0 * hy


@jit
def _inertia_to_world(b, R, p, out):
    """out = the parameters about the world origin, world axes, of the body parameters b
    (about the body's origin, body axes) of a body at axes R, origin p."""
    m = b[0]
    hx = R[0, 0] * b[1] + R[0, 1] * b[2] + R[0, 2] * b[3]
    hy = R[1, 0] * b[1] + R[1, 1] * b[2] + R[1, 2] * b[3]
    hz = R[2, 0] * b[1] + R[2, 1] * b[2] + R[2, 2] * b[3]
    xx, yy, zz, yz, xz, xy = b[4], b[5], b[6], b[7], b[8], b[9]
    # T = R J (J the body's rotational inertia), then R J R' = T R'
    t00 = R[0, 0] * xx + R[0, 1] * xy + R[0, 2] * xz
    t01 = R[0, 0] * xy + R[0, 1] * yy + R[0, 2] * yz
    t02 = R[0, 0] * xz + R[0, 1] * yz + R[0, 2] * zz
    t10 = R[1, 0] * xx + R[1, 1] * xy + R[1, 2] * xz
    t11 = R[1, 0] * xy + R[1, 1] * yy + R[1, 2] * yz
    t12 = R[1, 0] * xz + R[1, 1] * yz + R[1, 2] * zz
    t20 = R[2, 0] * xx + R[2, 1] * xy + R[2, 2] * xz
    t21 = R[2, 0] * xy + R[2, 1] * yy + R[2, 2] * yz
    t22 = R[2, 0] * xz + R[2, 1] * yz + R[2, 2] * zz
    j00 = t00 * R[0, 0] + t01 * R[0, 1] + t02 * R[0, 2]
    j11 = t10 * R[1, 0] + t11 * R[1, 1] + t12 * R[1, 2]
    j22 = t20 * R[2, 0] + t21 * R[2, 1] + t22 * R[2, 2]
    j12 = t10 * R[2, 0] + t11 * R[2, 1] + t12 * R[2, 2]
    j02 = t00 * R[2, 0] + t01 * R[2, 1] + t02 * R[2, 2]
    j01 = t00 * R[1, 0] + t01 * R[1, 1] + t02 * R[1, 2]
    px, py, pz = p[0], p[1], p[2]
    d = 2.0 * (hx * px + hy * py + hz * pz) + m * (px * px + py * py + pz * pz)
    out[0] = m
    out[1], out[2], out[3] = hx + m * px, hy + m * py, hz + m * pz
    out[4] = j00 + d - 2.0 * hx * px - m * px * px
    out[5] = j11 + d - 2.0 * hy * py - m * py * py
    out[6] = j22 + d - 2.0 * hz * pz - m * pz * pz
    out[7] = j12 - hy * pz - py * hz - m * py * pz
    out[8] = j02 - hx * pz - px * hz - m * px * pz
    out[9] = j01 - hx * py - px * hy - m * px * py


# -- coordinates and kinematics -------------------------------------------------------------
@jit
def full_coordinates(rows, q, passive, v):
    """(q, v) of every moving body from the listed joints' q, v and the passive positions."""
    nb = rows.shape[0]
    qf, vf = np.empty(nb), np.empty(nb)
    for i in range(nb):
        a, m = int(rows[i, ACTIVE]), rows[i, MULT]
        if a >= 0:
            qf[i] = m * q[a] + rows[i, OFFSET]
            vf[i] = m * v[a]
        else:
            qf[i] = m * passive[int(rows[i, PASSIVE])] + rows[i, OFFSET]
            vf[i] = 0.0
    return qf, vf


@jit
def _bodies(rows, qf, vf):
    """World axes Rw, origins pw, motion subspaces S, velocities vel and inertias Iw."""
    nb = rows.shape[0]
    Rw, pw = np.empty((nb, 3, 3)), np.empty((nb, 3))
    S, vel, Iw = np.empty((nb, 6)), np.empty((nb, 6)), np.empty((nb, 10))
    E, Rrel, prel = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    for i in range(nb):
        r = rows[i]
        ax, ay, az, x = r[AXIS], r[AXIS + 1], r[AXIS + 2], qf[i]
        if r[TYPE] == 0.0:                   # rotation by x about the axis (Rodrigues)
            c, s = math.cos(x), math.sin(x)
            t = 1.0 - c
            E[0, 0], E[0, 1], E[0, 2] = c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay
            E[1, 0], E[1, 1], E[1, 2] = t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax
            E[2, 0], E[2, 1], E[2, 2] = t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az
            for k in range(3):
                for j in range(3):
                    Rrel[k, j] = r[ROT + 3 * k] * E[0, j] + r[ROT + 3 * k + 1] * E[1, j] + \
                        r[ROT + 3 * k + 2] * E[2, j]
                prel[k] = r[POS + k]
        else:                                # translation by x along the axis
            for k in range(3):
                for j in range(3):
                    Rrel[k, j] = r[ROT + 3 * k + j]
                prel[k] = r[POS + k] + (r[ROT + 3 * k] * ax + r[ROT + 3 * k + 1] * ay +
                                        r[ROT + 3 * k + 2] * az) * x
        par = int(r[PARENT])
        if par < 0:
            Rw[i] = Rrel
            pw[i] = prel
        else:
            for k in range(3):
                for j in range(3):
                    Rw[i, k, j] = Rw[par, k, 0] * Rrel[0, j] + Rw[par, k, 1] * Rrel[1, j] + \
                        Rw[par, k, 2] * Rrel[2, j]
                pw[i, k] = pw[par, k] + Rw[par, k, 0] * prel[0] + Rw[par, k, 1] * prel[1] + \
                    Rw[par, k, 2] * prel[2]
        wx = Rw[i, 0, 0] * ax + Rw[i, 0, 1] * ay + Rw[i, 0, 2] * az
        wy = Rw[i, 1, 0] * ax + Rw[i, 1, 1] * ay + Rw[i, 1, 2] * az
        wz = Rw[i, 2, 0] * ax + Rw[i, 2, 1] * ay + Rw[i, 2, 2] * az
        if r[TYPE] == 0.0:                   # (w; p x w): rotation about the line through p
            px, py, pz = pw[i, 0], pw[i, 1], pw[i, 2]
            S[i, 0], S[i, 1], S[i, 2] = wx, wy, wz
            S[i, 3], S[i, 4], S[i, 5] = py * wz - pz * wy, pz * wx - px * wz, px * wy - py * wx
        else:
            S[i, 0], S[i, 1], S[i, 2] = 0.0, 0.0, 0.0
            S[i, 3], S[i, 4], S[i, 5] = wx, wy, wz
        for k in range(6):
            vel[i, k] = (vel[par, k] if par >= 0 else 0.0) + S[i, k] * vf[i]
        _inertia_to_world(r[INERTIA:INERTIA + 10], Rw[i], pw[i], Iw[i])
    return Rw, pw, S, vel, Iw


@jit
def _subtree_sums(rows, X):
    """Each row of X summed over its body's subtree (a copy)."""
    out = X.copy()
    for i in range(rows.shape[0] - 1, -1, -1):
        par = int(rows[i, PARENT])
        if par >= 0:
            out[par] += out[i]
    return out


# -- the full tree's terms ------------------------------------------------------------------
@jit
def _mass_full(rows, S, Ic):
    nb = rows.shape[0]
    M = np.zeros((nb, nb))
    F = np.empty(6)
    for j in range(nb):
        _inertia_times(Ic[j], S[j], F)
        i = j
        while i >= 0:
            M[i, j] = M[j, i] = _dot6(S[i], F)
            i = int(rows[i, PARENT])
        M[j, j] += rows[j, ARMATURE]
    return M


@jit
def _gravity_full(S, Ic):
    nb = S.shape[0]
    g = np.empty(nb)
    for i in range(nb):                      # Ic (0; 0, 0, G): n = h x (0, 0, G), f = m G
        G = GRAVITY
        g[i] = S[i, 0] * Ic[i, 2] * G - S[i, 1] * Ic[i, 1] * G + S[i, 5] * Ic[i, 0] * G
    return g


@jit
def _rnea_full(rows, S, vel, Iw, vf, af, gravity):
    """tau of every body's joint for accelerations af (gravity: the root accelerates up)."""
    nb = rows.shape[0]
    acc, f = np.empty((nb, 6)), np.empty((nb, 6))
    c, Iv, t = np.empty(6), np.empty(6), np.empty(6)
    for i in range(nb):
        par = int(rows[i, PARENT])
        _cross_motion(vel[i], S[i], c)
        for k in range(6):
            base = acc[par, k] if par >= 0 else (GRAVITY if (k == 5 and gravity) else 0.0)
            acc[i, k] = base + S[i, k] * af[i] + c[k] * vf[i]
        _inertia_times(Iw[i], acc[i], f[i])
        _inertia_times(Iw[i], vel[i], Iv)
        _cross_force(vel[i], Iv, t)
        for k in range(6):
            f[i, k] += t[k]
    f = _subtree_sums(rows, f)
    tau = np.empty(nb)
    for i in range(nb):
        tau[i] = _dot6(S[i], f[i]) + rows[i, ARMATURE] * af[i]
    return tau


@jit
def _mass_rate_full(rows, S, vel, Iw, Ic):
    """Mdot (no armature: it is constant)."""
    nb = rows.shape[0]
    rate = np.empty((nb, 10))
    for i in range(nb):
        _inertia_rate(Iw[i], vel[i], rate[i])
    rate = _subtree_sums(rows, rate)
    X = np.empty((nb, 6))                   # S_i' = v_i x S_i
    for i in range(nb):
        _cross_motion(vel[i], S[i], X[i])
    Md = np.zeros((nb, nb))                 # zero where neither joint is above the other
    F, G, y = np.empty(6), np.empty(6), np.empty(6)
    for j in range(nb):
        _inertia_times(Ic[j], S[j], F)
        _inertia_times(Ic[j], X[j], G)
        _inertia_times(rate[j], S[j], y)
        for k in range(6):
            G[k] += y[k]
        i = j
        while i >= 0:                       # -S_i . (v_i x* F_j) = (v_i x S_i) . F_j
            Md[i, j] = Md[j, i] = _dot6(S[i], G) + _dot6(X[i], F)
            i = int(rows[i, PARENT])
    return Md


@jit
def _coriolis_full(rows, S, vel, Iw, Ic, Md):
    """The Christoffel C of the full tree, (Mdot + P - P') / 2."""
    nb = rows.shape[0]
    Iv = np.empty((nb, 6))
    for i in range(nb):
        _inertia_times(Iw[i], vel[i], Iv[i])
    H = _subtree_sums(rows, Iv)
    W = np.zeros((nb, 6))
    for k in range(nb):
        par = int(rows[k, PARENT])
        if par >= 0:
            _cross_motion(vel[par], S[k], W[k])
    P = np.zeros((nb, nb))
    F, Pd, y = np.empty(6), np.empty(6), np.empty(6)
    for d in range(nb):
        _inertia_times(Ic[d], S[d], F)
        _cross_force(S[d], H[d], Pd)
        _inertia_times(Ic[d], W[d], y)
        for k in range(6):
            Pd[k] += y[k]
        a = d
        while a >= 0:
            P[d, a] = _dot6(F, W[a])
            if a != d:
                P[a, d] = _dot6(S[a], Pd)
            a = int(rows[a, PARENT])
    return 0.5 * (Md + P - P.T)


# -- reduction to the listed joints -----------------------------------------------------------
@jit
def _reduce_matrix(rows, n, A):
    out = np.zeros((n, n))
    for i in range(rows.shape[0]):
        ci = int(rows[i, ACTIVE])
        if ci < 0:
            continue
        for j in range(rows.shape[0]):
            cj = int(rows[j, ACTIVE])
            if cj >= 0:
                out[ci, cj] += rows[i, MULT] * rows[j, MULT] * A[i, j]
    return out


@jit
def _reduce_vector(rows, n, x):
    out = np.zeros(n)
    for i in range(rows.shape[0]):
        ci = int(rows[i, ACTIVE])
        if ci >= 0:
            out[ci] += rows[i, MULT] * x[i]
    return out


# -- entry points ------------------------------------------------------------------------------
@jit
def mass_matrix(rows, n, q, passive):
    qf, vf = full_coordinates(rows, q, passive, np.zeros(n))
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    return _reduce_matrix(rows, n, _mass_full(rows, S, _subtree_sums(rows, Iw)))


@jit
def gravity(rows, n, q, passive):
    qf, vf = full_coordinates(rows, q, passive, np.zeros(n))
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    return _reduce_vector(rows, n, _gravity_full(S, _subtree_sums(rows, Iw)))


@jit
def inverse_dynamics(rows, n, q, passive, v, a, with_gravity):
    """M a + C v (+ g with ``with_gravity``): the RNEA (a = 0: the bias C v + g)."""
    qf, vf = full_coordinates(rows, q, passive, v)
    af = full_coordinates(rows, a, np.zeros(passive.size), a)[1]
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    return _reduce_vector(rows, n, _rnea_full(rows, S, vel, Iw, vf, af, with_gravity))


@jit
def coriolis_matrix(rows, n, q, passive, v):
    qf, vf = full_coordinates(rows, q, passive, v)
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    Ic = _subtree_sums(rows, Iw)
    Md = _mass_rate_full(rows, S, vel, Iw, Ic)
    return _reduce_matrix(rows, n, _coriolis_full(rows, S, vel, Iw, Ic, Md))


@jit
def momentum_terms(rows, n, q, passive, v, mass):
    """[M (n x n, zeros without ``mass``), Mdot (n x n), C' v, g] in one flat array (one
    array handed back to Python, not four): what the torque estimators take per sample,
    from one kinematic pass; C' v = Mdot v - C v."""
    qf, vf = full_coordinates(rows, q, passive, v)
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    Ic = _subtree_sums(rows, Iw)
    out = np.zeros(2 * n * n + 2 * n)
    if mass:
        out[:n * n] = _reduce_matrix(rows, n, _mass_full(rows, S, Ic)).ravel()
    Md = _reduce_matrix(rows, n, _mass_rate_full(rows, S, vel, Iw, Ic))
    out[n * n:2 * n * n] = Md.ravel()
    cv = _reduce_vector(rows, n, _rnea_full(rows, S, vel, Iw, vf, np.zeros(qf.size), False))
    g = _reduce_vector(rows, n, _gravity_full(S, Ic))
    o = 2 * n * n
    for i in range(n):
        s = -cv[i]
        for k in range(n):
            s += Md[i, k] * v[k]
        out[o + i] = s
        out[o + n + i] = g[i]
    return out


@jit
def jacobian(rows, n, q, passive, body, origin):
    """6 x n: (linear; angular) velocity of the point ``origin`` (in body ``body``'s frame;
    -1: the root) in world axes per listed joint velocity."""
    qf, vf = full_coordinates(rows, q, passive, np.zeros(n))
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    J = np.zeros((6, n))
    if body < 0:
        return J
    o = np.empty(3)
    for k in range(3):
        o[k] = pw[body, k] + Rw[body, k, 0] * origin[0] + Rw[body, k, 1] * origin[1] + \
            Rw[body, k, 2] * origin[2]
    i = body
    while i >= 0:
        ci = int(rows[i, ACTIVE])
        if ci >= 0:
            m = rows[i, MULT]
            w0, w1, w2 = S[i, 0], S[i, 1], S[i, 2]
            J[0, ci] += m * (S[i, 3] + w1 * o[2] - w2 * o[1])
            J[1, ci] += m * (S[i, 4] + w2 * o[0] - w0 * o[2])
            J[2, ci] += m * (S[i, 5] + w0 * o[1] - w1 * o[0])
            J[3, ci] += m * w0
            J[4, ci] += m * w1
            J[5, ci] += m * w2
        i = int(rows[i, PARENT])
    return J


@jit
def frame_pose(rows, n, q, passive, body, axes, origin):
    """(R, p): the axes (3 x 3, columns in world axes) and the origin (world) of a frame
    whose axes and origin in body ``body``'s frame are ``axes``, ``origin`` (-1: the root)."""
    qf, vf = full_coordinates(rows, q, passive, np.zeros(n))
    Rw, pw, S, vel, Iw = _bodies(rows, qf, vf)
    R, p = np.empty((3, 3)), np.empty(3)
    if body < 0:
        R[:, :] = axes
        p[:] = origin
        return R, p
    for k in range(3):
        for j in range(3):
            R[k, j] = Rw[body, k, 0] * axes[0, j] + Rw[body, k, 1] * axes[1, j] + \
                Rw[body, k, 2] * axes[2, j]
        p[k] = pw[body, k] + Rw[body, k, 0] * origin[0] + Rw[body, k, 1] * origin[1] + \
            Rw[body, k, 2] * origin[2]
    return R, p
