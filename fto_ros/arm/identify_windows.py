"""The momentum identity in its window form, on the actual stamps of a recording (ROS-free):
the quadrature weights of the windows, the centred velocity, and the window sums the fit of
:mod:`.identify` is built from.

Weighting p' = tau + C^T v - g - tau_f + tau_ext with the kernel k(u) = kappa(u / T) / T,
kappa(s) = 30 s^2 (1 - s)^2 (k and k' vanish at both ends, integral 1) over the window
[t_e - T, t_e] and integrating by parts (docs/external_torque.md, eq. 2), with q~ = q - q(t_e):

    integral k tau  =  integral k'' M q~  -  integral k' Mdot q~  -  integral k (C^T v - g)
                     + b integral k' q~  +  f_c integral k tanh(v / w)  -  integral k tau_ext

(u = t_e - s the age of the instant s). Without contact the last term is 0, and the rest is
linear in the link inertial parameters (M, Mdot, C^T v and g are) and in b and f_c: one
equation per window and joint. The inertial and viscous terms need positions only; Mdot q~,
C^T v and the Coulomb term take the centred velocity (:func:`centred_velocity`: the
least-squares slope of the 2 m + 1 positions around each sample over their actual stamps;
offline every sample has its neighbours on both sides).

Quadrature on the actual stamps (jittered, some messages lost): between two samples the
positions and the model terms are interpolated linearly (hat functions on the stamps) and the
torque is held (it is the command of the earlier sample, acting until the next); the kernel
is a polynomial, so each hat function's integral against k, k' or k'' is computed exactly
(3-point Gauss-Legendre per interval, exact to degree 5). The kernel's steep shape thus adds
no quadrature error; what is left is the data's interpolation error, O(h^2 q'').
"""
from __future__ import annotations

import numpy as np
from scipy import sparse

from ..core.errors import FtoRosError
from ..core.jit import jit

#: Gauss-Legendre nodes and weights on [0, 1] (3 points)
_GL_X = np.array([0.5 - 0.5 * np.sqrt(0.6), 0.5, 0.5 + 0.5 * np.sqrt(0.6)])
_GL_W = np.array([5.0, 8.0, 5.0]) / 18.0


class WindowError(FtoRosError, ValueError):
    """A recording the window form cannot use (too short, a gap in every window)."""


@jit
def _kappa(s, order):
    """kappa (order 0), kappa' (1), kappa'' (2) at s in [0, 1]."""
    if order == 0:
        return 30.0 * s * s * (1.0 - s) * (1.0 - s)
    if order == 1:
        return 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s)
    return 60.0 * (1.0 - 6.0 * s + 6.0 * s * s)


def kernel(u, T: float, order: int = 0):
    """k^(order)(u) for ages u in [0, T] (0 outside): k = kappa(u / T) / T."""
    u = np.asarray(u, dtype=float)
    s = u / T
    inside = (s >= 0) & (s <= 1)
    val = np.where(inside, _kappa(np.clip(s, 0, 1), order), 0.0)
    return val / T ** (order + 1)


def centred_velocity(t: np.ndarray, q: np.ndarray, m: int = 6, degree: int = 3) -> np.ndarray:
    """Per sample, the slope at its stamp of the least-squares polynomial of ``degree``
    through the positions of the samples k - m .. k + m (the 2 m + 1 nearest at the ends)
    over their actual stamps. Degree 3: exact for a cubic, so a reversal where the Coulomb
    friction turns the acceleration round quickly (a large third derivative) biases it
    little."""
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    N = t.size
    if N < degree + 2:
        raise WindowError(f"a velocity needs at least {degree + 2} samples")
    width = min(2 * m + 1, N)
    lo = np.clip(np.arange(N) - m, 0, N - width)
    idx = lo[:, None] + np.arange(width)[None, :]
    dt = t[idx] - t[:, None]
    scale = np.maximum(np.abs(dt).max(axis=1, keepdims=True), 1e-300)
    V = (dt / scale)[:, :, None] ** np.arange(degree + 1)[None, None, :]
    slope = np.linalg.pinv(V)[:, 1, :] / scale          # d/dt of the fit at the sample
    return np.einsum("kj,kjn->kn", slope, q[idx])


@jit
def _weights(t, ends, T, first, glx, glw):
    """COO triplets of the four window operators (module doc): per window w (ending at
    sample ends[w]) and sample j, the weight of k'' (A2), k' (A1), k (A0, interpolated) and
    k over the hold interval of j (Z). first[w]: the first sample the window needs."""
    count = 0
    for w in range(ends.size):
        count += ends[w] - first[w] + 1
    rows = np.empty(count, np.int64)
    cols = np.empty(count, np.int64)
    vals = np.zeros((4, count))
    pos = 0
    for w in range(ends.size):
        e, a = ends[w], first[w]
        te = t[e]
        ts = te - T
        base = pos
        for j in range(a, e + 1):
            rows[pos] = w
            cols[pos] = j
            pos += 1
        for j in range(a, e):
            lo, hi = t[j], t[j + 1]
            span = hi - lo
            a_lo = lo if lo > ts else ts
            width = hi - a_lo
            if width <= 0.0:
                continue
            for g in range(glx.size):
                x = a_lo + glx[g] * width
                s = (te - x) / T
                if s < 0.0:
                    s = 0.0
                if s > 1.0:
                    s = 1.0
                wg = glw[g] * width
                right = (x - lo) / span
                left = 1.0 - right
                k0 = 30.0 * s * s * (1.0 - s) * (1.0 - s) / T
                k1 = 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s) / (T * T)
                k2 = 60.0 * (1.0 - 6.0 * s + 6.0 * s * s) / (T * T * T)
                i0 = base + j - a
                vals[0, i0] += wg * k2 * left
                vals[0, i0 + 1] += wg * k2 * right
                vals[1, i0] += wg * k1 * left
                vals[1, i0 + 1] += wg * k1 * right
                vals[2, i0] += wg * k0 * left
                vals[2, i0 + 1] += wg * k0 * right
                vals[3, i0] += wg * k0
    return rows, cols, vals


@jit
def _smooth_sign(t, ends, T, first, v, width, glx, glw):
    """integral k(u) tanh(v(t_e - u) / width) du per window and joint, v interpolated
    linearly between the samples and tanh evaluated at the Gauss-Legendre nodes (near a
    velocity reversal tanh changes within a sample period: interpolating tanh itself errs)."""
    out = np.zeros((ends.size, v.shape[1]))
    for w in range(ends.size):
        e, a = ends[w], first[w]
        te = t[e]
        ts = te - T
        for j in range(a, e):
            lo, hi = t[j], t[j + 1]
            a_lo = lo if lo > ts else ts
            width_j = hi - a_lo
            if width_j <= 0.0:
                continue
            for g in range(glx.size):
                x = a_lo + glx[g] * width_j
                s = (te - x) / T
                if s < 0.0:
                    s = 0.0
                if s > 1.0:
                    s = 1.0
                k0 = glw[g] * width_j * 30.0 * s * s * (1.0 - s) * (1.0 - s) / T
                right = (x - lo) / (hi - lo)
                for i in range(v.shape[1]):
                    vi = (1.0 - right) * v[j, i] + right * v[j + 1, i]
                    out[w, i] += k0 * np.tanh(vi / width)
    return out


class Windows:
    """The windows of a recording with stamps ``t`` (s, increasing): length ``T``, one
    ending every ``stride`` samples, none spanning a step longer than ``max_gap`` s.

    Attributes: ``ends`` (the last sample of each window), ``A2``, ``A1``, ``A0``, ``Z``
    (sparse, windows x samples: the weights of k'', k', k on interpolated data, k on held
    data), ``count``."""

    def __init__(self, t: np.ndarray, T: float, stride: int = 10, max_gap: float = 0.01,
                 mask: np.ndarray | None = None):
        t = np.asarray(t, dtype=float)
        if t.ndim != 1 or t.size < 3 or not np.all(np.diff(t) > 0):
            raise WindowError("the stamps must increase (at least 3 samples)")
        self.t, self.T = t, float(T)
        N = t.size
        # first[e]: the last sample at or before t_e - T
        first = np.searchsorted(t, t - T, side="right") - 1
        ok = first >= 0
        # no step longer than max_gap inside a window; mask: every sample usable
        bad = np.concatenate([[0], np.cumsum(np.diff(t) > max_gap)])
        use = np.ones(N, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        unusable = np.concatenate([[0], np.cumsum(~use)])
        fs = np.clip(first, 0, None)
        ok &= bad[np.arange(N)] - bad[fs] == 0
        ok &= unusable[np.arange(N) + 1] - unusable[fs] == 0
        candidates = np.flatnonzero(ok)
        ends = candidates[::max(1, int(stride))]
        if ends.size == 0:
            raise WindowError(f"no window of {T:g} s fits in the stretch ({t[-1] - t[0]:.3f} s"
                              f" of samples without a gap longer than {max_gap:g} s)")
        self.ends = ends.astype(np.int64)
        self.first = first[ends].astype(np.int64)
        rows, cols, vals = _weights(t, self.ends, self.T, self.first, _GL_X, _GL_W)
        shape = (ends.size, N)
        self.A2, self.A1, self.A0, self.Z = (
            sparse.csr_matrix((vals[i], (rows, cols)), shape=shape) for i in range(4))
        self.count = int(ends.size)

    def of_smooth_sign(self, v: np.ndarray, width: float) -> np.ndarray:
        """integral k tanh(v / width) per window (v interpolated, tanh at the nodes)."""
        return _smooth_sign(self.t, self.ends, self.T, self.first,
                            np.ascontiguousarray(v, dtype=float), float(width), _GL_X, _GL_W)

    def of_positions(self, q: np.ndarray, A) -> np.ndarray:
        """integral (weights A) of q~ = q - q(t_e), per window: (windows x n)."""
        return A @ q - np.asarray(A.sum(axis=1)) * q[self.ends]

    def of_matrix_times(self, M: np.ndarray, q: np.ndarray, A) -> np.ndarray:
        """integral (weights A) of M q~ per window: M (samples x n x n), q (samples x n)."""
        N, n = q.shape
        Mq = np.einsum("kij,kj->ki", M, q)
        AM = (A @ M.reshape(N, n * n)).reshape(-1, n, n)
        return A @ Mq - np.einsum("wij,wj->wi", AM, q[self.ends])

    def momentum(self, M: np.ndarray, Md: np.ndarray, q: np.ndarray) -> np.ndarray:
        """integral k'' M q~ - integral k' Mdot q~ per window (the momentum's part)."""
        return self.of_matrix_times(M, q, self.A2) - self.of_matrix_times(Md, q, self.A1)
