"""Levant's arbitrary-order robust exact differentiator (RED), properly discretised.

Continuous form (order n, N = n + 1, |f^(N)| <= L, innovation e = f - z0)::

    z_i' = z_(i+1) + l~_(n-i) L^((i+1)/N) |e|^((n-i)/N) sign(e)     (i < n)
    z_n' =           l~_0 L sign(e)

Three discretisations of it, all variable-step (h may change every sample):

``eigenvalue_matched`` (default)
    Freeze e, read the RED as a linear observer with all N poles at
    s(e) = -r |e|^(-1/N), r = rho L^(1/N), and place the N eigenvalues of the
    discrete closed loop Phi(h) - lambda e_1^T exactly at exp(h s) = 1 - w,
    w = -expm1(-h r |e|^(-1/N)) (w = 1, deadbeat, when e = 0)::

        z_(k+1) = Phi(h_k) z_k + lambda(w_k, h_k) e_k,   e_k = f_k - z0_k
        lambda_i = (i! / h^i) sum_(m=i+1..N) C(N, m) s(m-1, i) w^m / (m-1)!

    (s = signed Stirling numbers of the first kind), evaluated as powers of w.
    No chattering, exact for polynomials of degree <= n (deadbeat once e = 0
    there), insensitive to an overestimated L.
``livne_levant``
    Livne & Levant 2014: the Taylor shift Phi(h) plus the explicit-Euler
    correction h * [l~_(n-i) L^((i+1)/N) |e|^((n-i)/N) sign(e)]_i (e = f - z0:
    the sign is the opposite of the paper's e = z0 - f, so the correction is
    added).  Keeps the accuracy orders, chatters.
``euler``
    Plain explicit Euler z + h (shift z + correction): the naive baseline, for
    comparison only (loses the orders of the intermediate derivatives).

Filtering (``filter_order`` nf > 0, eigenvalue_matched only): nf integrators in
front of z0, x_1' = x_2, ..., x_nf' = z0 - f, the innovation is e = -x_1 and
the poles are placed for the whole chain of size N' = n + nf + 1 (r = rho
L^(1/N')).  Between samples z0 - f is held (equivalently, f is extrapolated by
the current estimates), which keeps the scheme exact for polynomials of degree
<= n; the gains come from Ackermann's formula in h-free scaled coordinates,
computed once in exact rational arithmetic.

``max_step``: a step longer than max_step is split into equal sub-steps with
the previous sample held (all schemes; the explicit schemes need it when the
sample rate is low for L, the default scheme does not).

**The estimate at t_k uses the sample taken at t_k.**  Each recursion above is a
predictor: z_k (the state) is made from f_0..f_(k-1); e_k = f_k - z0_k enters only
the next step.  Published as it is, that estimate lags by one sample (an error of
about h |f^(n+1)| on the top derivative).  What ``estimates`` publishes is the
current (filtered) estimate of the same recursion: the next prediction made with
f_k, shifted back along the chain over the same step,

    z+_k = Phi(h_k)^-1 step(z_k, f_k, h_k)        (= z_k + Phi(-h_k) lambda_k e_k),

h_k the last step.  The recursion (the state, its accuracy orders and its
exactness on polynomials) is unchanged; only what is read off it uses one sample
more.  On sin t + 0.5 sin 3t at 1 kHz without noise this divides the
second-derivative error by 1.8-2.5 (order 2 and 3; test/unit/core/test_differentiator.py).

Errors: bad constructor arguments, a bad step or sample, or a step whose result
would not be finite raise BadArgument (a ValueError) and leave the state untouched.

This module designs a differentiator; its step is compiled (core/differentiator_step.py:
every channel with the same arithmetic, the observers' kernels embed it in their state).
"""
from __future__ import annotations

import math
from fractions import Fraction
from typing import Sequence

import numpy as np

from . import differentiator_step as S
from .errors import BadArgument, NotReady

SCHEMES = ("eigenvalue_matched", "livne_levant", "euler")
MAX_ORDER = 7
#: largest n + filter_order + 1 accepted
MAX_CHAIN = 10
#: recursive gains lambda_0..lambda_7 (Levant)
RECURSIVE_LAMBDAS = (1.1, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0, 12.0)


# -- gains ---------------------------------------------------------------------------------
def recursive_to_nonrecursive(lambdas: Sequence[float]) -> tuple[float, ...]:
    """l~_0..l~_n from the recursive lambda_0..lambda_n:
    l~_n = lambda_n, l~_j = lambda_j l~_(j+1)^(j/(j+1)), l~_0 = lambda_0."""
    lam = [float(v) for v in lambdas]
    if len(lam) < 2:
        raise BadArgument("lambdas: need at least 2 values (order >= 1)")
    if not all(math.isfinite(v) and v > 0 for v in lam):
        raise BadArgument(f"lambdas: all must be finite and > 0, got {lam}")
    n = len(lam) - 1
    out = [0.0] * (n + 1)
    out[n] = lam[n]
    for j in range(n - 1, -1, -1):
        out[j] = lam[j] * out[j + 1] ** (j / (j + 1))
    return tuple(out)


def levant_gains(order: int) -> tuple[float, ...]:
    """Non-recursive gains l~_0..l~_n (l~_j multiplies L^((n-j+1)/N) |e|^(j/N) in the
    equation for z_(n-j)) from the recursive lambdas 1.1, 1.5, 2, 3, 5, 7, 10, 12."""
    _check_order(order)
    return recursive_to_nonrecursive(RECURSIVE_LAMBDAS[:order + 1])


def stirling1(m: int, i: int) -> int:
    """Signed Stirling number of the first kind s(m, i)."""
    row = [1]                                  # s(0, .)
    for k in range(m):                         # s(k+1, j) = s(k, j-1) - k s(k, j)
        row = [(row[j - 1] if j >= 1 else 0) - (k * row[j] if j < len(row) else 0)
               for j in range(len(row) + 1)]
    return row[i] if 0 <= i < len(row) else 0


def matched_gain_coefficients(N: int) -> np.ndarray:
    """K (N x N) with lambda_i = h^-i sum_m K[i, m-1] w^m (closed form, Stirling numbers)."""
    K = np.zeros((N, N))
    for i in range(N):
        for m in range(i + 1, N + 1):
            K[i, m - 1] = (math.factorial(i) * math.comb(N, m) * stirling1(m - 1, i)
                           / math.factorial(m - 1))
    return K


def matched_gains(order: int, w: float, h: float) -> np.ndarray:
    """lambda_0..lambda_n of the eigenvalue-matched scheme for one w and h (reference)."""
    N = order + 1
    K = matched_gain_coefficients(N)
    return (K @ (w ** np.arange(1, N + 1))) / h ** np.arange(N)


def _scaled_chain(N: int, nf: int) -> list[list[Fraction]]:
    """Transition matrix of the (filtered) chain in scaled coordinates y_p = h^p s_p.

    Positions 0..nf-1 are the filter integrators x_1..x_nf, nf..N-1 are z_0..z_n.  Within
    a block it is the Taylor shift 1/(q-p)!; x-rows see z_0 held: 1/(nf-p)!."""
    A = [[Fraction(0)] * N for _ in range(N)]
    for p in range(N):
        end = nf if p < nf else N
        for q in range(p, end):
            A[p][q] = Fraction(1, math.factorial(q - p))
        if p < nf:
            A[p][nf] = Fraction(1, math.factorial(nf - p))
    return A


def _fmatmul(A, B):
    n, m, k = len(A), len(B[0]), len(B)
    return [[sum((A[i][t] * B[t][j] for t in range(k)), Fraction(0)) for j in range(m)]
            for i in range(n)]


def _fsolve(A, b):
    """Solve A x = b exactly (Gauss-Jordan over the rationals)."""
    n = len(A)
    M = [list(A[i]) + [b[i]] for i in range(n)]
    for c in range(n):
        p = next(r for r in range(c, n) if M[r][c] != 0)
        M[c], M[p] = M[p], M[c]
        piv = M[c][c]
        M[c] = [v / piv for v in M[c]]
        for r in range(n):
            if r != c and M[r][c] != 0:
                f = M[r][c]
                M[r] = [a - f * bb for a, bb in zip(M[r], M[c])]
    return [M[i][n] for i in range(n)]


def ackermann_gain_coefficients(N: int, nf: int) -> np.ndarray:
    """K (N x N) with scaled gains lambda_bar = K @ [w, ..., w^N] placing all eigenvalues
    of A_bar - lambda_bar e_0^T at 1 - w (Ackermann: lambda = p(A) O^-1 e_last,
    p(z) = (z - 1 + w)^N = sum_m C(N, m) w^m (z - 1)^(N-m)); exact rationals."""
    A = _scaled_chain(N, nf)
    I = [[Fraction(int(i == j)) for j in range(N)] for i in range(N)]
    O = [[Fraction(int(j == 0)) for j in range(N)]]
    for _ in range(N - 1):
        O.append(_fmatmul([O[-1]], A)[0])
    v = _fsolve(O, [Fraction(int(i == N - 1)) for i in range(N)])
    AmI = [[A[i][j] - I[i][j] for j in range(N)] for i in range(N)]
    K = np.zeros((N, N))
    col = [[x] for x in v]                     # (A - I)^(N-m) v, from m = N downwards
    for m in range(N, 0, -1):
        for i in range(N):
            K[i, m - 1] = float(math.comb(N, m) * col[i][0])
        col = _fmatmul(AmI, col)
    return K


# -- argument checks -------------------------------------------------------------------------
def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _check_order(order) -> None:
    if not _is_int(order) or not 1 <= order <= MAX_ORDER:
        raise BadArgument(f"order: must be an integer in 1..{MAX_ORDER}, got {order!r}")


def _positive(name: str, v) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise BadArgument(f"{name}: must be a number, got {v!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise BadArgument(f"{name}: must be finite and > 0, got {v!r}")
    return x


# -- the differentiator ----------------------------------------------------------------------
class Differentiator:
    """Robust exact differentiator of order n for ``channels`` signals at once.

    Estimates z_0..z_n of f, f', ..., f^(n); L bounds |f^(n+1)|.  See the module
    docstring for the schemes.  ``update(h, f)`` is causal: it advances the state over h
    with the innovation of the previous sample, stores the new sample, and publishes the
    current estimate, which uses it (module doc).

    The design (gains, checks) is done here; the step is core/differentiator_step.py,
    compiled, over the descriptor ``consts`` and a state slice.  An observer kernel keeps
    both in its own arrays and steps them itself; ``on(state, offset)`` gives a view of
    such an embedded differentiator (estimates, residual, snapshots)."""

    def __init__(self, order: int, L: float, *, channels: int = 1,
                 scheme: str = "eigenvalue_matched", rho: float = 2.0,
                 gains: Sequence[float] | None = None,
                 filter_order: int = 0, max_step: float | None = None):
        _check_order(order)
        self.L = _positive("L", L)
        if not _is_int(channels) or channels < 1:
            raise BadArgument(f"channels: must be an integer >= 1, got {channels!r}")
        if scheme not in SCHEMES:
            raise BadArgument(f"scheme: must be one of {', '.join(SCHEMES)}, got {scheme!r}")
        self.rho = _positive("rho", rho)
        if not _is_int(filter_order) or filter_order < 0:
            raise BadArgument(f"filter_order: must be an integer >= 0, got {filter_order!r}")
        if order + filter_order + 1 > MAX_CHAIN:
            raise BadArgument(f"filter_order: order + filter_order must be <= {MAX_CHAIN - 1}, "
                             f"got {order} + {filter_order}")
        if filter_order and scheme != "eigenvalue_matched":
            raise BadArgument(f"filter_order: filtering is implemented for the "
                             f"eigenvalue_matched scheme only, not {scheme!r}")
        if gains is not None:
            if scheme == "eigenvalue_matched":
                raise BadArgument("gains: the eigenvalue_matched scheme places its poles from "
                                 "rho and L; gains apply to livne_levant and euler only")
            try:
                g = [float(v) for v in gains]
            except (TypeError, ValueError):
                raise BadArgument(f"gains: must be a sequence of numbers, got {gains!r}") from None
            if len(g) != order + 1:
                raise BadArgument(f"gains: need order + 1 = {order + 1} values l~_0..l~_n, "
                                 f"got {len(g)}")
            if not all(math.isfinite(v) and v > 0 for v in g):
                raise BadArgument(f"gains: all must be finite and > 0, got {g}")
            self.gains = tuple(g)
        else:
            self.gains = levant_gains(order)
        if max_step is not None:
            max_step = _positive("max_step", max_step)
        self.order = int(order)
        self.channels = int(channels)
        self.scheme = scheme
        self.filter_order = nf = int(filter_order)
        self.max_step = max_step
        n, N = self.order, self.order + 1
        self._N = NT = N + nf                  # full chain length
        self._nf = nf
        self._abar = np.array(_scaled_chain(NT, nf), dtype=float)
        self._K = np.zeros((NT, NT))
        self._bbar = np.zeros(NT)
        self._c = np.zeros(NT)
        self._r = 0.0
        if scheme == "eigenvalue_matched":
            self._r = self.rho * self.L ** (1.0 / NT)
            self._K = (matched_gain_coefficients(NT) if nf == 0
                       else ackermann_gain_coefficients(NT, nf))
            # input vector of f in scaled coordinates (times h^nf): -1/(nf-p)!
            self._bbar = np.array([-1.0 / math.factorial(nf - p) if p < nf else 0.0
                                   for p in range(NT)])
        else:
            # correction coefficients c_i = l~_(n-i) L^((i+1)/N)
            self._c = np.array([self.gains[n - i] * self.L ** ((i + 1) / N) for i in range(N)])
        # Phi(h)^-1 in scaled coordinates (entry (p, q) times h^(q-p)): unit upper
        # triangular, so the inverse is exact to round-off
        self._back = np.linalg.inv(np.eye(NT) + np.eye(NT, k=1) if scheme == "euler"
                                   else self._abar)
        head = [NT, nf, SCHEMES.index(scheme), self._r, max_step or 0.0, self.channels]
        #: the descriptor the compiled step reads (core/differentiator_step.py)
        self.consts = np.concatenate((head, self._abar.ravel(), self._K.ravel(), self._bbar,
                                      self._c, self._back.ravel()))
        #: floats of state and of scratch memory the step needs
        self.state_size = S.state_size(NT, self.channels)
        self.scratch_size = S.SCRATCH_PER_NT * NT
        self._wk = np.zeros(self.scratch_size)
        self._nx = np.zeros(self.state_size)
        self._f = np.zeros(self.channels)
        self._ready = False
        self._bind(np.zeros(self.state_size), 0)

    def _bind(self, st: np.ndarray, offset: int) -> None:
        self._st, self._so = st, int(offset)
        NT = self._N
        rows = st[self._so:self._so + self.state_size].reshape(self.channels, 2 * NT + 1)
        self._rows = rows
        self._view = rows[:, NT + self._nf:2 * NT]
        self._view.flags.writeable = False
        self._pred_view = rows[:, self._nf:NT]
        self._pred_view.flags.writeable = False

    # a copy (deepcopy, pickle) views its own copy of the state: numpy copies a view as an
    # independent array, which would leave the estimates frozen at the time of the copy
    _VIEWS = ("_rows", "_view", "_pred_view")

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in self._VIEWS}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._bind(self._st, self._so)

    def on(self, st: np.ndarray, offset: int) -> "Differentiator":
        """This differentiator with its state at ``st[offset:offset + state_size]`` (an
        observer's state, which its kernel steps): a view that reads and writes there."""
        view = object.__new__(type(self))
        view.__dict__.update(self.__dict__)
        view._ready = True
        view._bind(st, offset)
        return view

    # -- state ---------------------------------------------------------------------------
    def reset(self, f0, derivatives=None) -> None:
        """Start at the first sample f0 (channels,), derivatives (channels, n) initial guesses
        of f'..f^(n) (zeros if None); filter states at zero."""
        f0 = self._sample(f0)
        d = np.zeros(0)
        if derivatives is not None:
            d = np.asarray(derivatives, dtype=float)
            if d.size != self.channels * self.order:
                raise BadArgument(f"derivatives: need shape ({self.channels}, {self.order}), "
                                 f"got {d.shape}")
            d = np.ascontiguousarray(d, dtype=float).reshape(-1)
            if not np.all(np.isfinite(d)):
                raise BadArgument("derivatives: must be finite")
        S.reset(self.consts, 0, self._st, self._so, f0, d, derivatives is not None)
        self._ready = True

    def get_state(self):
        """Opaque snapshot (a copy) for set_state."""
        return (self._st[self._so:self._so + self.state_size].copy(), self._ready)

    def set_state(self, state) -> None:
        values, ready = state
        self._st[self._so:self._so + self.state_size] = values
        self._ready = ready

    @property
    def estimates(self) -> np.ndarray:
        """(channels, n + 1) read-only view of z_0..z_n at the last sample."""
        return self._view

    @property
    def predicted(self) -> np.ndarray:
        """(channels, n + 1) read-only view of the recursion's state z_k at the last sample
        (made from the samples before it; the accuracy theory is about this one)."""
        return self._pred_view

    @property
    def residual(self) -> np.ndarray:
        """|f - z0| per channel at the last sample: the innovation of the recursion."""
        return np.abs(self._rows[:, 2 * self._N] - self._rows[:, self._nf])

    # -- stepping ------------------------------------------------------------------------
    def _sample(self, f) -> np.ndarray:
        a = np.asarray(f, dtype=float).reshape(-1)
        if a.size != self.channels:
            raise BadArgument(f"f: need {self.channels} value(s), got {a.size}")
        if not np.all(np.isfinite(a)):
            raise BadArgument(f"f: must be finite, got {a}")
        return np.ascontiguousarray(a)

    def update(self, h: float, f) -> np.ndarray:
        """Advance by h > 0 with the previous sample's innovation, then take the sample f.
        Returns the current estimates at the new sample time, which use f (read-only view,
        shape (channels, n+1); module doc)."""
        if not self._ready:
            raise NotReady("Differentiator.update before reset()")
        if type(f) is float and self.channels == 1 and f - f == 0.0:
            fa = self._f
            fa[0] = f
        else:
            fa = self._sample(f)
        if not (h > 0 and h < math.inf):           # also rejects NaN
            raise BadArgument(f"h: the step must be finite and > 0, got {h!r}")
        nx = self._nx
        if S.update(self.consts, 0, self._st, self._so, nx, 0, float(h), fa, self._wk, 0):
            raise BadArgument(f"h: the step {h!r} gives a non-finite estimate; state unchanged")
        self._st[self._so:self._so + self.state_size] = nx
        return self._view

    def _mats(self, h: float):
        """(A(h)^T, h^-p, the filter input vector) of the recursion at step h in unscaled
        coordinates: the matrices the design is checked with (test/unit/core/test_differentiator.py)."""
        NT = self._N
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            hp = h ** np.arange(NT, dtype=float)
            hinv = 1.0 / hp
            if self.scheme == "euler":
                A = np.eye(NT) + h * np.eye(NT, k=1)
            else:
                A = (self._abar * hp[None, :]) * hinv[:, None]
            bvec = (self._bbar * h ** self._nf) * hinv
        return np.ascontiguousarray(A.T), hinv, bvec
