"""The external-torque estimators' per-sample steps: pure functions over flat float64 arrays.

Each is ``step(state, consts, h, y, u, ...) -> new state`` (y: the measured joint positions,
u: the torques commanded at this sample, which act until the next one); the terms of the
model (M, Mdot, C^T v, g, friction) are computed by the caller (the model, arm/dynamics.py)
and passed in as arrays. A step validates its inputs first and raises ``ValueError`` without touching
``state`` (it returns a new array). The ``make_*`` functions build ``consts`` and the initial
state; the ``*_view``/``*_output`` helpers read a state. docs/external_torque.md derives them.

- ``red_*``: Levant's robust exact differentiator per joint, the eigenvalue-matched scheme of
  :mod:`fto_ros.core.differentiator` (its gains; the same recursion and published estimate
  as ``Differentiator.update``): joint velocities.
- ``window_*``: the windowed momentum estimator: tau_ext averaged over the last T by a
  smooth kernel, exact T after any change (the package's design).
- ``gmo_*``: the generalized-momentum observer (De Luca et al.), the baseline.
- ``fd_*``: backward differences through the inverse dynamics, the naive baseline.
"""
from __future__ import annotations

import numpy as np

from ..core.differentiator import _scaled_chain, matched_gain_coefficients

#: largest |q| (rad or m) and |tau| (Nm or N) a step accepts
MAX_POSITION = 1e3
MAX_TORQUE = 1e6


def _check(h: float, y: np.ndarray, u: np.ndarray | None, n: int) -> None:
    if not (h > 0.0 and h < 1e3):
        raise ValueError(f"step h = {h!r}: must be finite and > 0")
    if y.shape != (n,) or not np.all(np.abs(y) < MAX_POSITION):
        raise ValueError(f"positions: need {n} finite values below {MAX_POSITION} in magnitude")
    if u is not None and (u.shape != (n,) or not np.all(np.abs(u) < MAX_TORQUE)):
        raise ValueError(f"torques: need {n} finite values below {MAX_TORQUE} in magnitude")


def _check_terms(*arrays: np.ndarray) -> None:
    for a in arrays:
        if not np.all(np.isfinite(a)):
            raise ValueError("model terms: not finite")


# -- robust exact differentiator: velocities -----------------------------------------------
def red_consts(order: int, L: float, rho: float = 2.0) -> np.ndarray:
    """[N, r, K (N x N), Taylor shift (N x N), its inverse (N x N)] of the eigenvalue-matched
    differentiator of ``order`` (N = order + 1) with bound L on the (order+1)-th derivative."""
    N = int(order) + 1
    if not (1 <= order <= 7 and L > 0 and rho > 0):
        raise ValueError("differentiator: order in 1..7, L > 0 and rho > 0")
    shift = np.array(_scaled_chain(N, 0), dtype=float)
    return np.concatenate([[N, rho * L ** (1.0 / N)], matched_gain_coefficients(N).ravel(),
                           shift.ravel(), np.linalg.inv(shift).ravel()])


def red_init(consts: np.ndarray, y: np.ndarray) -> np.ndarray:
    """State [z (n x N) predictor, post (n x N) published, y_prev (n)] started at y."""
    N, n = int(consts[0]), y.size
    z = np.zeros((n, N))
    z[:, 0] = y
    return np.concatenate([z.ravel(), z.ravel(), y])


def _red_unpack(consts):
    N = int(consts[0])
    K = consts[2:2 + N * N].reshape(N, N)
    A = consts[2 + N * N:2 + 2 * N * N].reshape(N, N)
    B = consts[2 + 2 * N * N:2 + 3 * N * N].reshape(N, N)
    return N, consts[1], K, A, B


def _red_advance(z, f, h, N, r, K, A):
    """One step of the recursion over h with the sample f (rows: channels)."""
    hp = h ** np.arange(N)
    At = (A * hp[None, :] / hp[:, None]).T
    e = f - z[:, 0]
    a = np.maximum(np.abs(e), 1e-300)
    w = -np.expm1(-(h * r) * a ** (-1.0 / N))
    W = w[:, None] ** np.arange(1, N + 1)
    return z @ At + (W @ K.T) / hp * e[:, None]


def red_step(state: np.ndarray, consts: np.ndarray, h: float, y: np.ndarray) -> np.ndarray:
    """Advance over h with the previous sample's innovation, take y; the published estimate
    uses y (as ``Differentiator.update``)."""
    N, r, K, A, B = _red_unpack(consts)
    n = y.size
    _check(h, y, None, n)
    z = state[:n * N].reshape(n, N)
    yprev = state[2 * n * N:]
    z1 = _red_advance(z, yprev, h, N, r, K, A)
    hp = h ** np.arange(N)
    back = (B * hp[None, :] / hp[:, None]).T
    post = _red_advance(z1, y, h, N, r, K, A) @ back
    if not (np.all(np.isfinite(z1)) and np.all(np.isfinite(post))):
        raise ValueError("differentiator: the step gives a non-finite estimate")
    return np.concatenate([z1.ravel(), post.ravel(), y])


def red_output(state: np.ndarray, consts: np.ndarray, n: int) -> np.ndarray:
    """(n, N) published estimates: position, velocity, ... per joint."""
    N = int(consts[0])
    return state[n * N:2 * n * N].reshape(n, N)


# -- the windowed momentum estimator ---------------------------------------------------------
def kernel(s: np.ndarray, derivative: int = 0) -> np.ndarray:
    """kappa(s) = 30 s^2 (1 - s)^2 on [0, 1] (integral 1; kappa, kappa' vanish at both ends)
    and its derivatives; ``derivative = -1``: its integral from 0, 10 s^3 - 15 s^4 + 6 s^5."""
    s = np.asarray(s, dtype=float)
    return {-1: 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5,
            0: 30 * s ** 2 * (1 - s) ** 2,
            1: 60 * s - 180 * s ** 2 + 120 * s ** 3,
            2: 60 - 360 * s + 360 * s ** 2}[derivative]


def gregory_weights(W: int) -> np.ndarray:
    """Quadrature weights (times h) on W + 1 equispaced nodes, exact for cubics: the
    trapezoid rule with third-order end corrections 17/48, 59/48, 43/48, 49/48 (W >= 8)."""
    if W < 8:
        raise ValueError("window: needs at least 8 samples")
    w = np.ones(W + 1)
    ends = np.array([17, 59, 43, 49]) / 48.0
    w[:4] = ends
    w[-4:] = ends[::-1]
    return w


#: default half-width (samples) of the centred velocity of the velocity-dependent terms
CENTRAL = 4


def window_consts(n: int, samples: int, h: float, viscous: np.ndarray,
                  central: int = CENTRAL) -> np.ndarray:
    """[n, W, h, m, viscous (n), a (W+1), b (W+1), c (W+1), d (W)] for a window of W = samples
    steps of h: a, b, c the quadrature weights of k'', k', k at u_j = j h (j = 0 newest),
    k(u) = kappa(u / T) / T, T = W h; d_j = the integral of k over [j h, (j+1) h]."""
    W = int(samples)
    T = W * h
    s = np.arange(W + 1) / W
    g = gregory_weights(W) * h
    a = g * kernel(s, 2) / T ** 3
    b = g * kernel(s, 1) / T ** 2
    c = g * kernel(s, 0) / T
    d = np.diff(kernel(s, -1))
    visc = np.broadcast_to(np.asarray(viscous, dtype=float), (n,))
    if not 1 <= int(central) <= W // 2:
        raise ValueError(f"central: 1..{W // 2} samples, got {central!r}")
    return np.concatenate([[n, W, h, int(central)], visc, a, b, c, d])


def _win_layout(consts):
    n, W = int(consts[0]), int(consts[1])
    slot = 5 * n + 2 * n * n              # q, Mq, Mdot q, phi, tau (n each); M, Mdot (n x n)
    return n, W, slot


def window_init(consts: np.ndarray) -> np.ndarray:
    """State [count, head, estimate (n), ring of W + 1 slots: q, M, Mq, Mdot, Mdot q, phi, tau]."""
    n, W, slot = _win_layout(consts)
    return np.zeros(2 + n + (W + 1) * slot)


def window_central(state: np.ndarray, consts: np.ndarray, y: np.ndarray):
    """(q, v) at sample k - m, v the least-squares slope of the 2 m + 1 positions
    around it (y = q_k the newest), or None before there are so many samples."""
    n, W, slot = _win_layout(consts)
    m = int(consts[3])
    if state[0] < 2 * m:
        return None
    head = int(state[1])
    ring = state[2 + n:].reshape(W + 1, slot)
    q = np.vstack([ring[(head - np.arange(2 * m - 1, -1, -1)) % (W + 1), :n], y[None, :]])
    i = np.arange(-m, m + 1, dtype=float)
    return q[m], (i @ q) / (consts[2] * (i @ i))


def window_step(state: np.ndarray, consts: np.ndarray, h: float, y: np.ndarray, u: np.ndarray,
                M: np.ndarray, Mdot: np.ndarray, phi: np.ndarray,
                Mdot_c: np.ndarray | None = None, phi_c: np.ndarray | None = None) -> np.ndarray:
    """Take the sample (y, u) with the model terms at it: M(q), Mdot(q, v), and
    phi = C(q, v)^T v - g(q) - f_c tanh(v / w) (the friction but its viscous part, which the
    window takes from the positions), provisional (at the differentiator's velocity); and
    ``Mdot_c``, ``phi_c`` at sample k - m with the centred velocity of
    :func:`window_central`, which replace its provisional ones (None while there is no such
    sample). Estimate tau_ext once W + 1 samples are in."""
    n, W, slot = _win_layout(consts)
    h0 = consts[2]
    _check(h, y, u, n)
    if abs(h - h0) > 1e-3 * h0:
        raise ValueError(f"step h = {h!r}: the window needs the nominal period {h0!r}")
    _check_terms(M, Mdot, phi)
    if Mdot_c is not None:
        _check_terms(Mdot_c, phi_c)
    visc = consts[4:4 + n]
    off = 4 + n
    a, b, c = (consts[off + i * (W + 1):off + (i + 1) * (W + 1)] for i in range(3))
    d = consts[off + 3 * (W + 1):off + 3 * (W + 1) + W]
    new = state.copy()
    count, head = int(state[0]) + 1, (int(state[1]) + 1) % (W + 1)
    ring = new[2 + n:].reshape(W + 1, slot)
    ring[head] = np.concatenate([y, M.ravel(), M @ y, Mdot.ravel(), Mdot @ y, phi, u])
    if Mdot_c is not None:
        old = ring[(head - int(consts[3])) % (W + 1)]
        old[2 * n + n * n:2 * n + 2 * n * n] = Mdot_c.ravel()
        old[2 * n + 2 * n * n:3 * n + 2 * n * n] = Mdot_c @ old[:n]
        old[3 * n + 2 * n * n:4 * n + 2 * n * n] = phi_c
    new[0], new[1] = min(count, W + 1), head
    if count < W + 1:
        return new
    order = (head - np.arange(W + 1)) % (W + 1)          # j = 0 newest
    R = ring[order]
    q = R[:, :n]
    Ms = R[:, n:n + n * n].reshape(W + 1, n, n)
    Mq = R[:, n + n * n:2 * n + n * n]
    Md = R[:, 2 * n + n * n:2 * n + 2 * n * n].reshape(W + 1, n, n)
    Mdq = R[:, 2 * n + 2 * n * n:3 * n + 2 * n * n]
    ph = R[:, 3 * n + 2 * n * n:4 * n + 2 * n * n]
    tau = R[1:, 4 * n + 2 * n * n:]                       # tau_(k-j-1) acts on cell j
    qc = y
    est = (a @ Mq - np.einsum("j,jik->ik", a, Ms) @ qc
           - b @ Mdq + np.einsum("j,jik->ik", b, Md) @ qc
           + visc * (b @ (q - qc)) - c @ ph - d @ tau)
    if not np.all(np.isfinite(est)):
        raise ValueError("window: non-finite estimate")
    new[2:2 + n] = est
    return new


def window_output(state: np.ndarray, consts: np.ndarray) -> np.ndarray | None:
    """The current tau_ext estimate, or None before the window is full."""
    n, W = int(consts[0]), int(consts[1])
    return state[2:2 + n] if state[0] >= W + 1 else None


# -- generalized-momentum observer -----------------------------------------------------------
def gmo_init(n: int) -> np.ndarray:
    """State [started, integral (n), residual (n), p0 (n), beta_prev (n), tau_prev (n)]."""
    return np.zeros(1 + 5 * n)


def gmo_step(state: np.ndarray, gain: np.ndarray, h: float, y: np.ndarray, u: np.ndarray,
             p: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """r_k = K_O (p_k - p_0 - I_k), I_k = I_(k-1) + h (tau_(k-1) + (beta_(k-1) + beta_k) / 2
    + r_(k-1)); p = M v and beta = C^T v - g - tau_f(v) at the velocity estimate."""
    n = y.size
    _check(h, y, u, n)
    _check_terms(p, beta)
    new = state.copy()
    I, r, p0, bp, tp = (new[1 + i * n:1 + (i + 1) * n] for i in range(5))
    if state[0] == 0.0:
        new[0] = 1.0
        p0[:] = p
    else:
        I += h * (tp + 0.5 * (bp + beta) + r)
        r[:] = gain * (p - p0 - I)
    bp[:], tp[:] = beta, u
    if not np.all(np.isfinite(new)):
        raise ValueError("momentum observer: non-finite state")
    return new


def gmo_output(state: np.ndarray, n: int) -> np.ndarray:
    return state[1 + n:1 + 2 * n]


# -- finite differences ----------------------------------------------------------------------
def fd_init(n: int) -> np.ndarray:
    """State [count, q_(k-1) (n), q_(k-2) (n), v (n), tau_prev (n), estimate (n)]."""
    return np.zeros(1 + 5 * n)


def fd_velocity(state: np.ndarray, h: float, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v, a): backward differences of the positions (zeros before there are samples)."""
    n = y.size
    k = int(state[0])
    q1, q2 = state[1:1 + n], state[1 + n:1 + 2 * n]
    v = (y - q1) / h if k >= 1 else np.zeros(n)
    a = (y - 2 * q1 + q2) / (h * h) if k >= 2 else np.zeros(n)
    return v, a


def fd_step(state: np.ndarray, h: float, y: np.ndarray, u: np.ndarray,
            inverse_dynamics: np.ndarray) -> np.ndarray:
    """tau_ext = M a + C v + g + tau_f (``inverse_dynamics``, at the differences) - tau_(k-1)."""
    n = y.size
    _check(h, y, u, n)
    _check_terms(inverse_dynamics)
    new = state.copy()
    k = int(state[0])
    v, _ = fd_velocity(state, h, y)
    new[1 + 4 * n:] = inverse_dynamics - state[1 + 3 * n:1 + 4 * n] if k >= 2 else 0.0
    new[1 + n:1 + 2 * n] = state[1:1 + n]
    new[1:1 + n] = y
    new[1 + 2 * n:1 + 3 * n] = v
    new[1 + 3 * n:1 + 4 * n] = u
    new[0] = min(k + 1, 2)
    return new


def fd_output(state: np.ndarray, n: int) -> np.ndarray:
    return state[1 + 4 * n:]
