"""What the two single-delay kernels share (protocol: observers/kernel.py): the layout of
their arrays, the restart, the first sample, the delay ring's use and the output.  The
per-sample steps are in continuous.py (Theorem 1) and sampled.py (Theorem 2).

State:  header | x_hat (n) | z (N) | omega (q) | y (q) | u (m) | xi_e (n1) | w (W) |
        xi2_0 (q) | has xi2_0 | s | ring indices [start, cursor, end]
        z = [xh1, xh2, psi1, psi2] (N = 3 n1 + q) at model time s; omega the sampled form's
        predictor (z and omega adjacent: its state Z); y, u the last sample's (u: the input
        in force); w = [F1, F2, Y] of the last sample (W = n1 + 2q, continuous form); xi2_0
        the xh2 a restart from an estimate gives.
Consts: header | k, tau, fill step, substep, ring min gap, ring window | Pmap (n x n),
        Md (n1 x N), MdA (n1 x N), MdB (n1 x W), Me (n1 x N), R (n1 x q), A2 (q x n1), then
        the form's own: continuous Az (N x N), Bz (N x W), Mo (3 n1 x (N + W)); sampled the predictor's
        (A, B) before and after t0 + tau ((N + q) x (N + q), (N + q) x (2 n1 + q)).
Ints:   header | n1, q, m, foh | offsets of the state blocks, of the matrices in c, of the
        ring, the step cache(s) and the scratch in wk | cache slots (each), ring capacity
Work:   the step cache(s) (core/step_cache.py), the delay ring (core/delay_buffer.py: the
        delayed combination dl = Md z and its derivative, indices in the state: a rejected
        sample takes its pushes back with its candidate state), the scratch (this module's
        part first: common_scratch() floats).
Models: [F(y, u) = (F1, F2 + k y)] (n1 + q terms; the sampled form evaluates it at omega).

The ring keeps every entry of one delay window up to E = c[WINDOW] of them (the adapter's
WINDOW_ENTRIES); beyond, pushes closer than tau / E to the newest are skipped (thinned,
core/delay_buffer.py).  Each sample trims what lies before its read at s - tau, so at most
2 E + 2 committed entries remain (+1 for rounding), plus what one sample pushes: the
capacity (RING_SLACK covers the rounding).
"""
from __future__ import annotations

import math

import numpy as np

from ...core import jit as J
from ...core.delay_buffer import CURSOR, START, ring_floats, ring_push, ring_read
from ...core.jit import jit, numba
from ...core.linalg import matvec
from ...core.reasons import CODE
from ...core.step_cache import cache_init
from .. import kernel as K

_I = K.IC_HEADER
N1, Q, M, FOH = range(_I, _I + 4)
S_Z, S_OM, S_Y, S_U, S_XI, S_W, S_X2I, S_HAS_X2I, S_T, S_RING = range(_I + 4, _I + 14)
C_PMAP, C_MD, C_MDA, C_MDB, C_ME, C_R, C_A2, C_A, C_B, C_A_AFTER, C_B_AFTER, C_MO = \
    range(_I + 14, _I + 26)
W_RING, W_CAP, W_CACHE, W_CACHE_AFTER, W_SLOTS, W_SCRATCH = range(_I + 26, _I + 32)
IC_SIZE = _I + 32
# float constants after the protocol's header
K_, TAU, FILL_STEP, SUBSTEP, MIN_GAP, WINDOW = range(K.C_HEADER, K.C_HEADER + 6)

NON_FINITE_TERM = CODE["non_finite_model_term"]
NON_FINITE = CODE["non_finite_estimate"]
#: the estimate is the paper's (13), reading the ring at s - tau, from s >= tau - this on
CONVERGED_SLACK = 1e-9
#: ring entries beyond the 2 E + 2 of one window and one sample's pushes (rounding)
RING_SLACK = 8


def ring_capacity(window: int, pushes: int) -> int:
    """The ring's entries for a window of ``window`` entries and a form that pushes at most
    ``pushes`` per sample."""
    return 2 * window + RING_SLACK + pushes


def build(n1, q, m, foh, advance, max_step, scalars, mats, caches, ring_cap, scratch):
    """(c, ic, wk, state size) of a kernel (``advance``: it takes ADVANCE): ``scalars`` (k,
    tau, fill step, substep, ring min gap, ring window), ``mats`` {C_ index: matrix} in
    order, ``caches`` [(W_ index, slots, floats)], the ring's capacity and the form's scratch
    floats (after common_scratch)."""
    n, N, W = n1 + q, 3 * n1 + q, n1 + 2 * q
    ic = np.zeros(IC_SIZE, dtype=np.int64)
    ic[:_I] = K.layout_ic(n, K.HEADER, has_advance=advance)
    ic[N1], ic[Q], ic[M], ic[FOH] = n1, q, m, int(foh)
    off = K.HEADER + n
    for key, width in zip((S_Z, S_OM, S_Y, S_U, S_XI, S_W, S_X2I, S_HAS_X2I, S_T, S_RING),
                          (N, q, q, m, n1, W, q, 1, 1, 3)):
        ic[key] = off
        off += width
    parts = [np.array([max_step, *scalars], dtype=float)]
    off = sum(p.size for p in parts)
    for key, A in mats.items():
        ic[key] = off
        parts.append(np.ascontiguousarray(A, dtype=float).ravel())
        off += A.size
    sizes = []
    off = 0
    for key, slots, floats in caches:
        ic[key], ic[W_SLOTS] = off, slots
        sizes.append((off, slots))
        off += floats
    ic[W_RING], ic[W_CAP] = off, ring_cap
    off += ring_floats(ring_cap, n1)
    ic[W_SCRATCH] = off
    wk = np.zeros(off + common_scratch(n1, q, m) + scratch)
    for base, slots in sizes:
        cache_init(wk, base, slots)
    return np.concatenate(parts), ic, wk, ic[S_RING] + 3


@jit
def common_scratch(n1, q, m):
    """Floats of the scratch this module's helpers use (at the start of the scratch)."""
    return (n1 + q) + 3 * n1


@jit
def mat(c, off, rows, cols):
    return c[off:off + rows * cols].reshape(rows, cols)


@jit
def mv(A, x, out):
    """out = A x as numpy's ``A @ x``: BLAS gemv, a dot product for one row (numpy's choice;
    gemv sums a single row in another order)."""
    if A.shape[0] == 1:
        out[0] = np.dot(A[0], x)
    else:
        matvec(A, x, out)


@jit
def same(a, b):
    for i in range(a.shape[0]):
        if a[i] != b[i]:
            return False
    return True


@jit
def converged(c, s):
    return s >= c[TAU] - CONVERGED_SLACK


@jit
def model_w(models, x, y, u, out, q):
    """out = w = [F1(y, u), F2(y, u), y] (n1 + 2q); the model's code (1: not finite)."""
    nf = out.shape[0] - q
    code = models[0](x, y, u, out[:nf])
    out[nf:] = y
    return code


@jit
def _common(wk, ic):
    """The shared scratch: the published vector (n), three n1 vectors."""
    n1, q = ic[N1], ic[Q]
    o = ic[W_SCRATCH]
    vec = wk[o:o + n1 + q]
    o += n1 + q
    return vec, wk[o:o + n1], wk[o + n1:o + 2 * n1], wk[o + 2 * n1:o + 3 * n1]


@jit
def delayed(nx, c, ic, wk, s, out):
    """out = dl(s - tau), read from the candidate's ring (the read moves its cursor)."""
    ring = nx[ic[S_RING]:ic[S_RING] + 3]
    ring_read(wk, ic[W_RING], ic[W_CAP], ic[N1], ring, s - c[TAU], out)


@jit
def push(st, nx, c, ic, wk, t, z, w):
    """Push (t, dl = Md z, dl' = MdA z + MdB w) onto the candidate's ring (skipped when it is
    closer than the min gap to the newest entry)."""
    n1, q = ic[N1], ic[Q]
    N = 3 * n1 + q
    W = n1 + 2 * q
    vec, d1, d2, d3 = _common(wk, ic)
    mv(mat(c, ic[C_MD], n1, N), z, d1)
    mv(mat(c, ic[C_MDA], n1, N), z, d2)
    mv(mat(c, ic[C_MDB], n1, W), w, d3)
    for i in range(n1):
        d2[i] = d2[i] + d3[i]
    push_entry(st, nx, c, ic, wk, t, d1, d2)


@jit
def push_entry(st, nx, c, ic, wk, t, dl, ddl):
    """Push (t, dl, dl') onto the candidate's ring, sparing the committed entries (skipped
    when t is closer than the min gap to the newest entry)."""
    ring_push(wk, ic[W_RING], ic[W_CAP], ic[N1], nx[ic[S_RING]:ic[S_RING] + 3],
              int(st[ic[S_RING] + START]), t, dl, ddl, c[MIN_GAP], int(c[WINDOW]))


@jit
def trim(nx, ic):
    nx[ic[S_RING] + START] = nx[ic[S_RING] + CURSOR]


@jit
def publish(nx, c, ic, wk, xi2):
    """x_hat = Pmap [xi_e; xi2]."""
    n1, q = ic[N1], ic[Q]
    n = n1 + q
    vec, d1, d2, d3 = _common(wk, ic)
    vec[:n1] = nx[ic[S_XI]:ic[S_XI] + n1]
    vec[n1:] = xi2
    mv(mat(c, ic[C_PMAP], n, n), vec, nx[K.HEADER:K.HEADER + n])


def _solve_np(P, x):
    return np.ascontiguousarray(np.linalg.solve(P, x))


def _solve_jit(P, x):
    with numba.objmode(out="float64[::1]"):
        out = _solve_np(P, x)
    return out


#: P^-1 x by numpy's own solve (LAPACK), as the adapter computed restarts before: a restart
#: is rare, its numbers are those of the numpy path
solve_exact = _solve_np if not J.ENABLED else jit(_solve_jit, gil=True)


@jit
def restart(st, c, ic, x0, has_x0):
    """Forget the run: z = [xi1 of x0 (or 0), 0, 0, 0], an empty ring; xh2 starts at xi2 of x0
    (if given) or at the first sample."""
    n1, q, m = ic[N1], ic[Q], ic[M]
    n = n1 + q
    N = 3 * n1 + q
    z = st[ic[S_Z]:ic[S_Z] + N]
    z[:] = 0.0
    st[ic[S_HAS_X2I]] = 0.0
    if has_x0:
        xi = solve_exact(mat(c, ic[C_PMAP], n, n), x0)
        z[:n1] = xi[:n1]
        st[ic[S_X2I]:ic[S_X2I] + q] = xi[n1:]
        st[ic[S_HAS_X2I]] = 1.0
    st[ic[S_U]:ic[S_U] + m] = 0.0
    st[ic[S_RING]:ic[S_RING] + 3] = 0.0
    st[K.RESIDUAL] = math.nan
    st[K.HEALTH] = 0.0
    return 0


@jit
def first(st, nx, c, ic, wk, y, u, models):
    """The first sample after a restart (model time 0): xh2 = Y unless a restart gave it, the
    ring's first entry, omega = Y, xi_e = xh1."""
    n1, q, m = ic[N1], ic[Q], ic[M]
    N = 3 * n1 + q
    W = n1 + 2 * q
    z = nx[ic[S_Z]:ic[S_Z] + N]
    if st[ic[S_HAS_X2I]] > 0.0:
        z[n1:n1 + q] = st[ic[S_X2I]:ic[S_X2I] + q]
    else:
        z[n1:n1 + q] = y
    w = nx[ic[S_W]:ic[S_W] + W]
    if model_w(models, st, y, u, w, q) != 0:
        return NON_FINITE_TERM
    push(st, nx, c, ic, wk, 0.0, z, w)
    nx[ic[S_T]] = 0.0
    nx[ic[S_Y]:ic[S_Y] + q] = y
    nx[ic[S_U]:ic[S_U] + m] = u
    nx[ic[S_OM]:ic[S_OM] + q] = y
    nx[ic[S_XI]:ic[S_XI] + n1] = z[:n1]
    publish(nx, c, ic, wk, y)
    return 0
