"""The robust exact differentiator's per-sample step, compiled (core/jit.py), over arrays.

core/differentiator.py designs a differentiator (gains, schemes, checks) and packs it into
a **descriptor**, a float array that an owner (an observer kernel, or the Differentiator
class itself) keeps among its constants at offset ``co``:

    [NT, nf, scheme, r, max_step (0: none), channels,
     abar (NT x NT), K (NT x NT), bbar (NT), c (NT), back (NT x NT)]

NT = n + nf + 1 the chain length, scheme 0/1/2 = eigenvalue_matched / livne_levant / euler,
r = rho L^(1/NT), abar the Taylor shift in h-scaled coordinates, K the matched gains'
coefficients (lambda_p = h^-p sum_m K[p, m] w^(m+1)), bbar the filter input vector, c the
explicit schemes' correction coefficients, back = abar^-1 (Phi(h)^-1 scaled).  The state of
``channels`` signals is a slice of the owner's state at ``so``, per channel

    [z (NT): the recursion's state | z+ (NT): the published estimate | the last sample]

Every channel is stepped with the same arithmetic in the same order as the unrolled
single-channel step the package generated before this module (terms skipped where a
coefficient is zero, sums left to right, powers of h and w by repeated products), so the
estimates are bit for bit those of the previous code on one channel.  No allocation: the
scratch (``SCRATCH_PER_NT`` x NT floats) is the owner's work memory.  ROS-free.
"""
from __future__ import annotations

import math

from .jit import jit

HEAD = 6
MATCHED, LIVNE_LEVANT, EULER = 0, 1, 2
#: scratch floats per chain element: powers of h, 1/h and w, two state buffers, z+
SCRATCH_PER_NT = 6


def descriptor_size(NT: int) -> int:
    return HEAD + 3 * NT * NT + 2 * NT


def state_size(NT: int, channels: int) -> int:
    return channels * (2 * NT + 1)


@jit
def _powers(h, NT, hp):
    """hp = 1, h, h^2, ... by repeated products."""
    hp[0] = 1.0
    for k in range(1, NT):
        hp[k] = h if k == 1 else hp[k - 1] * h


@jit
def _shifted(c, mo, NT, p, v, hp):
    """v_p + sum_(q > p) M[p, q] h^(q-p) v_q, M the upper triangular NT x NT matrix at
    c[mo:], zero entries skipped (the Taylor shift or its inverse, in h-scaled form)."""
    acc = v[p]
    for q in range(p + 1, NT):
        mpq = c[mo + p * NT + q]
        if mpq != 0.0:
            acc += mpq * hp[q - p] * v[q]
    return acc


@jit
def _step(c, co, z, fp, h, out, hp, ih, wp):
    """out = one step of the recursion from z with the sample fp over h (out, z distinct)."""
    NT = int(c[co])
    nf = int(c[co + 1])
    scheme = int(c[co + 2])
    A = co + HEAD
    Kg = A + NT * NT
    bb = Kg + NT * NT
    cc = bb + NT
    _powers(h, NT, hp)
    if scheme == MATCHED:
        e = fp - z[0] if nf == 0 else -z[0]
        a = e if e >= 0.0 else -e
        w = -math.expm1(-h * c[co + 3] * a ** (-1.0 / NT)) if a > 0.0 else 1.0
        wp[0] = w
        for m in range(1, NT):
            wp[m] = wp[m - 1] * w
        ih[0] = 1.0
        for k in range(1, NT):
            ih[k] = 1.0 / h if k == 1 else ih[k - 1] * ih[1]
        for p in range(NT):
            acc = _shifted(c, A, NT, p, z, hp)
            g = 0.0
            have = False
            for m in range(NT):
                kpm = c[Kg + p * NT + m]
                if kpm != 0.0:
                    g = g + kpm * wp[m] if have else kpm * wp[m]
                    have = True
            if have:
                acc += g * e * ih[p] if p else g * e
            if nf and p < nf and c[bb + p] != 0.0:
                acc += c[bb + p] * hp[nf - p] * fp
            out[p] = acc
        return
    # livne_levant, euler: the explicit correction h c_i |e|^((n-i)/N) sign(e)
    e = fp - z[0]
    s = h if e > 0.0 else (-h if e < 0.0 else 0.0)
    qv = (e if e >= 0.0 else -e) ** (1.0 / NT)
    wp[NT - 1] = s
    for i in range(NT - 2, -1, -1):
        wp[i] = wp[i + 1] * qv
    for p in range(NT):
        if scheme == EULER:
            acc = z[p] + h * z[p + 1] if p + 1 < NT else z[p]
        else:
            acc = _shifted(c, A, NT, p, z, hp)
        out[p] = acc + c[cc + p] * wp[p]


@jit
def _back(c, co, n, h, out, hp):
    """out = Phi(h)^-1 n: shift the chain n back over h (the current estimate)."""
    NT = int(c[co])
    bk = co + HEAD + 2 * NT * NT + 2 * NT
    _powers(h, NT, hp)
    for p in range(NT):
        out[p] = _shifted(c, bk, NT, p, n, hp)


@jit
def update(c, co, src, so, dst, do, h, f, wk, wo):
    """Advance every channel by h > 0 with its previous sample's innovation (in sub-steps of
    at most max_step, the previous sample held), then take the samples f (channels): the
    new state goes to dst at do (src at so is read only; they may be the same array only
    at the same offset).  0, or 1 when a result would not be finite (dst is then partly
    written: the caller discards it)."""
    NT = int(c[co])
    max_step = c[co + 4]
    channels = int(c[co + 5])
    hp = wk[wo:wo + NT]
    ih = wk[wo + NT:wo + 2 * NT]
    wp = wk[wo + 2 * NT:wo + 3 * NT]
    za = wk[wo + 3 * NT:wo + 4 * NT]
    zb = wk[wo + 4 * NT:wo + 5 * NT]
    zp = wk[wo + 5 * NT:wo + 6 * NT]
    width = 2 * NT + 1
    for ch in range(channels):
        s0 = so + ch * width
        fp = src[s0 + 2 * NT]
        hs = h
        steps = 1
        if max_step > 0.0 and h > max_step:
            steps = int(math.ceil(h / max_step - 1e-9))
            hs = h / steps
        za[:] = src[s0:s0 + NT]
        for _ in range(steps):
            _step(c, co, za, fp, hs, zb, hp, ih, wp)
            za[:] = zb
        # the current estimate: the prediction made with the new sample, shifted back
        _step(c, co, za, f[ch], hs, zb, hp, ih, wp)
        _back(c, co, zb, hs, zp, hp)
        t1 = 0.0
        t2 = 0.0
        for i in range(NT):
            t1 += za[i]
            t2 += zp[i]
        t = t1 + t2
        if t - t != 0.0:
            return 1
        d0 = do + ch * width
        dst[d0:d0 + NT] = za
        dst[d0 + NT:d0 + 2 * NT] = zp
        dst[d0 + 2 * NT] = f[ch]
    return 0


@jit
def reset(c, co, dst, do, f0, d, has_d):
    """Start every channel at the sample f0[ch]: z_n.. = (f0, d[ch, 0..n-1] or 0), filter
    states 0; the estimate is the state (no step yet)."""
    NT = int(c[co])
    nf = int(c[co + 1])
    channels = int(c[co + 5])
    order = NT - nf - 1
    width = 2 * NT + 1
    for ch in range(channels):
        d0 = do + ch * width
        for i in range(NT):
            dst[d0 + i] = 0.0
        dst[d0 + nf] = f0[ch]
        if has_d:
            for i in range(order):
                dst[d0 + nf + 1 + i] = d[ch * order + i]
        dst[d0 + NT:d0 + 2 * NT] = dst[d0:d0 + NT]
        dst[d0 + 2 * NT] = f0[ch]


@jit
def residual(c, co, st, so, ch):
    """|f - z0| of channel ch at its last sample: the recursion's innovation."""
    NT = int(c[co])
    nf = int(c[co + 1])
    s0 = so + ch * (2 * NT + 1)
    return abs(st[s0 + 2 * NT] - st[s0 + nf])
