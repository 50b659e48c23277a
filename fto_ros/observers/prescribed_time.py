"""Prescribed-time observer for linear SISO plants in observer canonical form
(Holloway & Krstic 2019, IEEE TAC 64(9)), running continuously.

Plant (eq. 1-6), any order n, relative degree r = n - rho:

    x' = A x - a y + [0_(r-1); b] u (+ F(y, u), optional known output terms),  y = x_1

A the upper shift, a = (a_{n-1}, ..., a_0), b = (b_rho, ..., b_0).  Observer (7):

    x_hat' = A x_hat - a y + [0; b] u + g(t - t0, T) (y - x_hat_1)

with the gains (22)-(23), polynomials in mu_1 = T / (T + t0 - t) (Lemma 4), built
from the coefficients p_bar of the recursion (18)-(21) (cross-checked against the
closed form of Proposition 1 in the tests).  The estimation error tends to 0 as
t -> t0 + T whatever the initial conditions (Theorem 1).

**The step.**  Lemma 1 is an exact change of coordinates: z~ = W(t) x~ with
W = mu_1^(n+m) P*(mu_1) turns the error system (8)-(9) into z~' = Lambda z~ (26),
time invariant.  So the transition matrix of the error system over [t_a, t_b] is
known in closed form,

    Phi(t_b, t_a) = W(t_b)^-1 e^(Lambda (t_b - t_a)) W(t_a),

and it is evaluated in a scaled form whose every factor stays bounded up to and
including t_b = t0 + T (where Phi = 0):

    Phi = diag(k^i rho^(n+m-i)) C^-1 diag((rho/beta)^i) E_bar(h) diag(beta^i) C diag(k^-i)

with k = 1/(T - s_a), beta = h k <= 1, rho = (T - s_b) k = 1 - beta, C the integer
matrix c_ij = p_bar_ij T^(i-j) (its inverse computed exactly once) and
E_bar(h) = e^(H Lambda H^-1 h), H = diag(h^(i-1)), cached per step size.

Between samples y is known only at the samples.  The observer is split exactly
into the plant model and a correction c driven by g (y - x_model_1); relative to
the model started from x_hat(t_k), the residual r = y - x_model_1 is
e_1' e^(A s) x~(t_k) (+ the model mismatch), a polynomial in s.  It is taken
linear between r_k and r_k+1 (a first-order hold of the *residual*, not of y),
and y between samples is x_model_1 + r_lin everywhere, also in the -a y term: the
model runs with the plant's own matrix A - a e_1' and -a r_lin as an input, r_k+1
solving one scalar equation.  Then, exactly,

    x_hat(t_k+1) = x_model(t_k+1) + e^(A h) q - Phi(t_k+1, t_k) q,
    q = (r_k, (r_k+1 - r_k)/h, 0, ...),

and an exact estimate stays exact over a step (no floor from holding y).  For
n <= 2 this is the exact solution of (7); for n >= 3 the hold drops the
s^2/2 x~_3 + ... part of the residual: an O(h^2) error proportional to the
current error.  Late in a window the observer's bandwidth, about rho_nm / (T - s),
outruns what a linear hold can feed it from n = 5 on: there the window ends at
the sampling limit (bandwidth x step = ``sampling_limit``).  Steps are on the
house's 1 us grid, counted as an integer from an anchor stamp, so the model time
never drifts from the stamps.

**Continuous operation** (Section II-A): a window ends at s_end = min(T, t_stop,
the time the largest |g_i| reaches g_max, the sampling limit).  Then, by ``mode``:
``restart`` (default) starts a new window there with the current estimate as its
initial condition, forever; ``stop`` turns the injections off (open-loop model
from then on); ``constant`` freezes the gains at their window-end value (a
constant-gain Luenberger observer from then on).
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from scipy.linalg import expm

from ..core.discretize import MAX_SUBSTEPS, STEP_QUANTUM, ExactStepper, StepCache, quanta
from ..core.expressions import VectorFunction
from .base import ConfigError, Observer, Param, SampleRejected, matrix

#: the longest prescribed time (s) accepted: beyond ~1e10 s the window's model time no
#: longer counts whole microseconds exactly in a double (2^53 us)
MAX_T = 1e9

P = "prescribed_time."

#: largest plant order accepted (C's integer entries and the gain polynomials stay
#: far below 2^53 and double range there; tested up to n = 10, m = 20)
MAX_ORDER = 10
MAX_M = 20


# ---------------------------------------------------------------------------
# design quantities of the paper: p_bar (18)-(21), Proposition 1, gains (22)-(23)
# ---------------------------------------------------------------------------
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


def _inverse_unit_lower(C: list[list[int]]) -> np.ndarray:
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


def bandwidth_factor(n: int, m: int) -> float:
    """rho_nm: the observer's bandwidth is about rho_nm / (T - s) late in a window.

    Largest |root| of s^n + c_1 s^(n-1) + ... + c_n with c_i = h_bar_ii T^i, the
    leading coefficients of the gains (T-free); those dominate as mu_1 grows.
    """
    H = gain_coefficients(n, m, 1.0, np.zeros(n))
    return float(np.max(np.abs(hurwitz_roots([H[i, i + 1] for i in range(n)]))))


#: order from which the sampling guard is on by default, and its default value
GUARD_FROM_ORDER = 5
GUARD_DEFAULT = 0.1


def _balanced_expm(col: np.ndarray, h: float) -> np.ndarray:
    """e^(H (N - col e_1') H^-1 h) with H = diag(h^(i-1)), N the upper shift.

    The balanced matrix has 1 on the superdiagonal and -col_i h^i in the first
    column, so expm's normwise accuracy is accuracy where it matters.
    """
    n = col.size
    M = np.diag(np.ones(n - 1), 1) if n > 1 else np.zeros((1, 1))
    M[:, 0] = -col * h ** np.arange(1, n + 1)
    return expm(M)


class PrescribedTimeObserver(Observer):
    TYPE = "prescribed_time"
    DESCRIPTION = ("Holloway & Krstic 2019: exact at the prescribed time T whatever the initial "
                   "conditions; linear SISO plants in observer canonical form, any order")
    HEALTH_NAME = "largest |gamma_i| = |g_i (y - x_hat_1)|, the output injection terms"
    PARAMS = (
        Param("n_states", "int", None, "plant order n", min=1, max=MAX_ORDER),
        Param("relative_degree", "int", None, "relative degree r = n - rho of the plant (1..n)",
              min=1, max=MAX_ORDER),
        Param("n_inputs", "int", 1, "number of known inputs: 1, or 0 for an unforced plant "
              "(then b is empty)", min=0, max=1),
        Param("a", "double_array", None, "(a_{n-1}, ..., a_0) of eq. (1)-(5): the output "
              "coefficients, n values (x_i' = x_{i+1} - a_{n-i} y + ...)", read_only=False),
        Param("b", "double_array", [], "(b_rho, ..., b_0) of eq. (3)-(5): n - r + 1 input "
              "coefficients, b_rho != 0 (empty when n_inputs = 0)", read_only=False),
        Param("T", "double", None, "the prescribed convergence time (s) after each (re)start "
              "of a window, > 0", min=0.0, read_only=False),
        Param("m", "int", 1, "design integer m >= 1 of eq. (13): larger m, faster final "
              "convergence (error ~ (1 - s/T)^(m+1)), larger gains", min=1, max=MAX_M,
              read_only=False),
        Param("l", "double_array", None, "l_1..l_n: s^n + l_1 s^(n-1) + ... + l_n must be "
              "Hurwitz (eq. 26)", read_only=False),
        Param("mode", "string", "restart", "after the window end (T, t_stop, g_max or the "
              "sampling limit): 'restart' a new window there with the current estimate "
              "(forever), 'stop' the injections (open-loop model copy), or freeze the gains "
              "at their end value ('constant')", choices=("restart", "stop", "constant"),
              read_only=False),
        Param("g_max", "double", 0.0, "end the window when the largest gain (absolute value) reaches g_max "
              "(Section II-A; 0: no cap)", min=0.0, read_only=False),
        Param("t_stop", "double", 0.0, "end the window t_stop s after its start, <= T "
              "(0: at T)", min=0.0, read_only=False),
        Param("sampling_limit", "double", -1.0, "end the window at the first sample where the "
              "observer bandwidth (about rho_nm / (T - s)) times the sample step reaches this: "
              "a faster observer needs y between samples (orders >= 5). -1: automatic (none for "
              "n <= 4, 0.1 from n = 5); 0: never", min=-1.0, read_only=False),
        Param("input_hold", "string", "zoh", "u between samples: held (zoh, like a DAC) or "
              "linear (foh)", choices=("zoh", "foh"), read_only=False),
        Param("F", "string_array", [], "optional n known terms in y0 and u0 added to the plant "
              "equations (output injection, e.g. '-35*sin(y0)'); empty: none", read_only=False),
        Param("state_map", "double_array", [], "n x n matrix S with x_published = S x_canonical "
              "(empty: identity, publish the canonical-form state)", read_only=False),
        Param("reset_keeps_estimate", "bool", True, "a restart without observer.initial_estimate "
              "(~/reset, time jump, gap) keeps the current estimate (moved on to the next sample) "
              "as the new window's initial condition; false: start from zero", read_only=False),
        Param("state_names", "string_array", [], "names of the n published states "
              "(empty: x1, x2, ...)"),
    )

    def __init__(self, cfg: dict):
        n, r, p_in = cfg["n_states"], cfg["relative_degree"], cfg["n_inputs"]
        if n is None:
            raise ConfigError(P + "n_states", "required: the plant order n")
        if r is None:
            raise ConfigError(P + "relative_degree", "required: the relative degree r (1..n)")
        if not 1 <= r <= n:
            raise ConfigError(P + "relative_degree", f"must be in 1..n = 1..{n}, got {r}")
        self.n_states, self.n_outputs, self.n_inputs = n, 1, p_in
        self.n, self.r = n, r
        a = cfg["a"]
        if a is None or len(a) != n:
            raise ConfigError(P + "a", f"expected n = {n} values (a_{n - 1}, ..., a_0), got "
                              f"{'nothing' if a is None else len(a)}")
        b = cfg["b"] or []
        rho = n - r
        if p_in == 0:
            if b:
                raise ConfigError(P + "b", "must be empty when n_inputs = 0")
        else:
            if len(b) != rho + 1:
                raise ConfigError(P + "b", f"expected n - r + 1 = {rho + 1} values (b_{rho}, ..., "
                                  f"b_0) for n = {n}, r = {r}; got {len(b)}")
            if b[0] == 0.0:
                raise ConfigError(P + "b", f"b_{rho} (the first value) must be nonzero, else the "
                                  f"relative degree is not r = {r}")
        T = cfg["T"]
        if T is None or not T > 0:
            raise ConfigError(P + "T", f"must be > 0 (it is the convergence time), got {T}")
        if not STEP_QUANTUM <= T <= MAX_T:
            raise ConfigError(P + "T", f"must be between {STEP_QUANTUM:g} s (the runner's time "
                              f"quantum) and {MAX_T:g} s, got {T:g}")
        m = cfg["m"]
        l = cfg["l"]
        if l is None or len(l) != n:
            raise ConfigError(P + "l", f"expected n = {n} values l_1..l_n, got "
                              f"{'nothing' if l is None else len(l)}")
        l = np.asarray(l, dtype=float)
        roots = hurwitz_roots(l)
        if not np.all(roots.real < 0):
            raise ConfigError(P + "l", "s^n + l_1 s^(n-1) + ... + l_n is not Hurwitz (roots "
                              + ", ".join(f"{z:.4g}" for z in roots)
                              + "): every root needs a negative real part, e.g. l from "
                              "(s + 1)^n = binomial coefficients")
        self.a = np.asarray(a, dtype=float)
        self.b = np.asarray(b, dtype=float)
        self.T, self.m, self.l = float(T), int(m), l
        self.l_roots = roots

        # -- the paper's design ------------------------------------------------
        Cint = c_matrix(n, m)
        self.C = np.array(Cint, dtype=float)
        self.Cinv = _inverse_unit_lower(Cint)
        self.pbar = p_bar(n, m, self.T)
        self.Hg = gain_coefficients(n, m, self.T, l)           # g_i(mu) = Hg[i] . mu^k
        self._k = np.arange(n + 1, dtype=float)
        self._mu_pow = np.empty(n + 1)
        self._g = np.empty(n)
        self._i = np.arange(1, n + 1, dtype=float)
        self._hpow_exp = np.arange(n, dtype=float)             # h^(i-1)
        self._nm = n + m
        self._bases = np.ones((4, 1))
        self._exps = np.vstack([self._i] * 4)
        self._scal = np.empty((4, n))

        # -- end of a window: T, t_stop, g_max (Section II-A), sampling guard ---
        self.mode = cfg["mode"]
        g_max, t_stop = cfg["g_max"], cfg["t_stop"]
        if t_stop > self.T:
            raise ConfigError(P + "t_stop", f"must be <= T = {self.T:g} (0: at T), got {t_stop:g}")
        s_end, self.end_reason = self.T, "T"
        if 0 < t_stop < s_end:
            s_end, self.end_reason = t_stop, "t_stop"
        self.g_max = g_max
        if g_max > 0:
            g0 = float(np.max(np.abs(self.gains_at(1.0))))
            if g_max <= g0:
                raise ConfigError(P + "g_max", f"the gains start at {g0:.4g} (largest |g_i| at "
                                  f"t = t0): g_max must be larger, got {g_max:g}")
            s_cap = self.T * (1.0 - 1.0 / self._mu_at_gain(g_max))
            if s_cap < s_end:
                s_end, self.end_reason = s_cap, "g_max"
        self.s_end = s_end
        self.rho_nm = bandwidth_factor(n, m)
        lim = cfg["sampling_limit"]
        if lim < 0:
            lim = GUARD_DEFAULT if n >= GUARD_FROM_ORDER else 0.0
        self.sampling_limit = lim
        # the guard in terms of beta = h / (T - s): fewer than 1/beta samples left
        self.beta_guard = lim / self.rho_nm if lim > 0 else math.inf
        self.g_end = None if s_end >= self.T else self.gains_at(self.T / (self.T - s_end)).copy()
        if self.mode == "constant":
            if self.g_end is None and math.isinf(self.beta_guard):
                raise ConfigError(P + "mode", "'constant' freezes the gains at the window end: set "
                                  "g_max > 0, 0 < t_stop < T or sampling_limit > 0 (at T the "
                                  "gains are infinite)")
            if self.g_end is not None:
                self._check_frozen(self.g_end)

        # -- plant model between samples ------------------------------------------
        # y between samples is reconstructed as y_rec = x_m,1 + r_lin (the model's own
        # output plus the linear residual), in the -a y term as in the injection, so
        # the model runs with the plant's matrix A_p = A - a e_1' and -a r_lin as an
        # input: x_m' = A_p x_m + B w,  w = (u, F(y, u), r).  With that, a correct
        # estimate stays correct over a step (no floor from the hold of y).
        A = np.diag(np.ones(n - 1), 1) if n > 1 else np.zeros((1, 1))
        self.A = A
        Ap = A.copy()
        Ap[:, 0] -= self.a
        cols = []
        if p_in:
            bvec = np.zeros((n, 1))
            bvec[r - 1:, 0] = self.b
            cols.append(bvec)
        self.F = None
        if cfg["F"]:
            self.F = VectorFunction(cfg["F"], 1, p_in, P + "F", length=n)
            if self.F.is_zero:
                self.F = None
            else:
                cols.append(np.eye(n))
        cols.append(-self.a[:, None])
        self.model = ExactStepper(Ap, np.hstack(cols))
        W = self.model.m
        self._ir0 = n + W - 1                    # r(t_k) in [x; w0; w1]
        self._ir1 = n + 2 * W - 1                # r(t_k+1)
        self._iu1 = n + W                        # u(t_k) is at n (n_inputs <= 1)
        self._sl_f0 = slice(n + p_in, n + W - 1)
        self._sl_f1 = slice(n + W + p_in, n + 2 * W - 1)
        self._zbuf = np.zeros(n + 2 * W)
        self._q = np.zeros(n)
        self._step_cache = StepCache(self._step_matrices)
        self.foh_input = cfg["input_hold"] == "foh"

        if cfg["state_map"]:
            self.Smap = matrix(cfg, "state_map", n, n, P)
            if np.linalg.matrix_rank(self.Smap) < n:
                raise ConfigError(P + "state_map", "must be invertible")
        else:
            self.Smap = None
        self.state_names = cfg["state_names"] or [f"x{i + 1}" for i in range(n)]
        if len(self.state_names) != n:
            raise ConfigError(P + "state_names", f"expected {n} names, got {len(self.state_names)}")
        self.reset_keeps_estimate = cfg["reset_keeps_estimate"]

        self._ebar_cache = StepCache(lambda h: _balanced_expm(self.l, h))
        self._after_cache = StepCache(self._after_matrix)
        self._x = np.zeros(n)
        self._x_pub = np.zeros(n)
        self._t = None
        self._prev = None          # (t, y, u, F(y, u), y - x_hat_1) of the last sample
        self._kstart = 0           # model quanta of the sample the clock (re)started at
        self._tw = 0.0             # start of the current window, from the anchor
        self._after = False        # past the window end (modes stop / constant)
        # the constant mode's gains (set when the window ends); None: injections off
        self._frozen = self.g_end if self.mode == "constant" else None
        self.last_end = None       # (time, reason) of the last window end
        self.restarts = 0          # window restarts since reset (mode restart)
        self.restarts_total = 0
        self._residual = float("nan")
        self._post = 0.0
        self._zeros = np.zeros(n)
        self._infs = np.full(n, np.inf)
        self._g_peak = 0.0
        self._health = 0.0

    def _check_frozen(self, g: np.ndarray) -> None:
        eig = hurwitz_roots(g)
        if not np.all(eig.real < 0):
            raise ConfigError(P + "mode", "'constant': the frozen gains "
                              f"{np.array2string(g, precision=4)} do not give a Hurwitz "
                              "A - g e_1' (eigenvalues " + ", ".join(f"{z:.4g}" for z in eig)
                              + "); choose another g_max / t_stop")

    # -- the paper's functions ----------------------------------------------------
    def gains_at(self, mu: float) -> np.ndarray:
        """g_1..g_n at mu_1 = mu (Lemma 4 polynomials), into a preallocated buffer."""
        np.power(mu, self._k, out=self._mu_pow)
        np.dot(self.Hg, self._mu_pow, out=self._g)
        return self._g

    def _mu_at_gain(self, g_max: float) -> float:
        """Smallest mu_1 >= 1 at which some |g_i(mu_1)| reaches g_max (inf if never)."""
        best = math.inf
        for i in range(self.n):
            for sign in (1.0, -1.0):
                c = self.Hg[i, :i + 2].copy()          # g_(i+1) has degree i + 1
                c[0] -= sign * g_max
                c = np.trim_zeros(c, "b")
                if c.size < 2:
                    continue
                for z in np.roots(c[::-1]):
                    if abs(z.imag) <= 1e-9 * max(1.0, abs(z)) and z.real >= 1.0:
                        best = min(best, float(z.real))
        return best

    def transition_window(self, v: np.ndarray, sa: float, sb: float) -> np.ndarray:
        """Phi(t0 + sb, t0 + sa) v for the error system (8)-(9) inside one window, 0 <= sa < sb <= T.

        Exact (Lemma 1): the scaled product of the module docstring; sb = T gives 0.
        """
        T = self.T
        h = sb - sa
        if not h > 0.0:
            return v
        kap = 1.0 / (T - sa)
        beta = h * kap
        rho = max(T - sb, 0.0) * kap
        if rho <= 0.0:
            return np.zeros(self.n)             # the window ends at T: Phi = 0
        # every diagonal scaling from one power call: rows k^-i, beta^i, (rho/beta)^i,
        # (k/rho)^i; and k^i rho^(n+m-i) = rho^(n+m) (k/rho)^i
        b = self._bases
        b[0, 0] = 1.0 / kap
        b[1, 0] = beta
        b[2, 0] = rho / beta
        b[3, 0] = kap / rho
        s = np.power(b, self._exps, out=self._scal)
        w = self.C @ (v * s[0])
        w *= s[1]
        w = self._ebar(h) @ w
        w *= s[2]
        w = self.Cinv @ w
        w *= s[3]
        w *= rho ** self._nm
        return w

    # -- cached step matrices --------------------------------------------------------
    def _ebar(self, h: float) -> np.ndarray:
        return self._ebar_cache(max(h, 1e-9))

    def _after_matrix(self, h: float) -> np.ndarray:
        """H^-1 e^(...) H past the window end: free (stop) or frozen gains (constant)."""
        col = np.zeros(self.n) if self._frozen is None else self._frozen
        E = _balanced_expm(col, h)
        return E / h ** self._hpow_exp[:, None] * h ** self._hpow_exp[None, :]

    def _after_step(self, v: np.ndarray, h: float) -> np.ndarray:
        """Transition past the window end (the cache is cleared when _frozen changes)."""
        return self._after_cache(max(h, 1e-9)) @ v

    # -- protocol ---------------------------------------------------------------------
    # Model time: whole quanta (core.discretize.STEP_QUANTUM) since the first sample ever
    # (the anchor), continued across warm restarts; the base class's clock restarts at
    # every reset at model quanta _kstart.
    def _restart(self, x0_hat):
        """Start a new window at the next sample.

        Without x0_hat and with ``reset_keeps_estimate``, the current estimate is
        kept (moved on to that sample by a step of the old window when the gap to it
        is at most T; beyond, the old window says nothing useful and x is kept as is).
        """
        if x0_hat is not None:
            self._x = np.linalg.solve(self.Smap, x0_hat) if self.Smap is not None else x0_hat.copy()
            self._prev = None
        elif not self.reset_keeps_estimate:
            self._x = np.zeros(self.n)
            self._prev = None
        self._t = None

    @property
    def max_step(self):
        # a step crossing window ends costs one transition per window: at most MAX_SUBSTEPS
        return self.s_end * MAX_SUBSTEPS if self.mode == "restart" else math.inf

    def _w(self, u, f, r: float) -> np.ndarray:
        """w = (u, F(y, u), r) (F only when given)."""
        if f is None:
            return np.concatenate((u, (r,)))
        return np.concatenate((u, f, (r,)))

    def _f(self, y, u):
        if self.F is None:
            return None
        f = self.F(y, u)
        if not math.isfinite(sum(f)):
            raise SampleRejected("non_finite_model_term")
        return f

    def _step(self, s, h, y, u):
        self._apply(y, u, *self._compute(self._kstart + quanta(s), y, u))

    def _first(self, y, u, gap):
        f = self._f(y, u)
        x = self._x
        k, post = 0, None
        if self._prev is not None and gap is not None and 0 < gap <= self.T:
            # warm restart: finish the old window's step up to this sample, then start anew
            try:
                k, x, post = self._compute(self._prev[0] + quanta(gap), y, u)[:3]
            except SampleRejected:
                k, x = self._prev[0] + quanta(gap), self._x       # keep the estimate as it is
        elif self._prev is not None:
            k = self._prev[0] + 1          # model time keeps increasing; the gap is not bridged
        if post is None:
            post = float(y[0] - x[0])
        self._x = x
        self._kstart = k
        self._tw = k * STEP_QUANTUM             # the window starts at this sample
        self._after, self._frozen = False, (self.g_end if self.mode == "constant" else None)
        self._after_cache.clear()
        self.restarts, self._g_peak, self.last_end = 0, 0.0, None
        self._commit(k, y, u, f, post, abs(post))

    def _step_matrices(self, h: float):
        """([Phi | G0 | G1] of the model, its r(t_k+1) column, 1 / (1 + that column's 1st entry))."""
        S = self.model.stacked(h)
        g1 = S[:, self._ir1].copy()
        den = 1.0 + g1[0]
        return S, g1, 1.0 / den if abs(den) > 1e-9 else math.nan

    def _compute(self, k, y, u):
        """The step from the last sample to model quanta k; nothing is committed
        (SampleRejected leaves the state as it was)."""
        kp, yp, up, fp, r0 = self._prev
        n = self.n
        # model time: an integer number of STEP_QUANTUM (1 us): steps hit cached matrices
        # even for jittery live stamps, and the model time never drifts from the stamps (a
        # drift of 0.5 us in the time of a sample is 1e-3 of error once the gains
        # differentiate over one step at the end of a window)
        h = (k - kp) * STEP_QUANTUM
        tp, t = kp * STEP_QUANTUM, k * STEP_QUANTUM
        u_end = u if self.foh_input else up
        f1 = self._f(y, u_end)
        S, g1, inv_den = self._step_cache(h)
        if math.isnan(inv_den):
            raise SampleRejected("step_too_long")
        # [x_hat; w0; w1] with w = (u, F, r) and r(t_k+1) = 0 for now
        z = self._zbuf
        z[:n] = self._x
        if self.n_inputs:
            z[n] = up[0]
            z[self._iu1] = u_end[0]
        if fp is not None:
            z[self._sl_f0] = fp
            z[self._sl_f1] = f1
        z[self._ir0] = r0
        # model prediction, then solve y = x_m,1 for r1 (one scalar equation: x_m
        # depends on r1 through the -a r_lin input)
        xm = S @ z
        r1 = (float(y[0]) - xm[0]) * inv_den
        xm += g1 * r1
        q = self._q
        q[0] = r0
        if n > 1:
            q[1] = (r1 - r0) / h
        d, win = self._propagate(q, tp, t)
        # x_hat = x_model + e^(A h) q - Phi q,  e^(A h) q = (q1 + h q2, q2, 0, ...)
        x = xm - d
        if n > 1:
            x[0] = y[0] - d[0]                  # = xm_1 + r1 - (Phi q)_1, without rounding
            x[1] += q[1]
            post = float(d[0])                  # y - x_hat_1 after the step, exactly
        else:
            x[0] += r0
            post = float(y[0] - x[0])
        if not math.isfinite(x.sum() + r1):
            raise SampleRejected("non_finite_estimate")
        win = self._guard(t, h, win)
        # F(y, u) at the start of the next step (u may have changed at t)
        f_next = f1 if (f1 is None or u is u_end or np.array_equal(u, u_end)) else self._f(y, u)
        return k, x, post, float(r1), win, f_next

    def _apply(self, y, u, k, x, post, r1, win, f_next):
        self._x = x
        tw, after, frozen, restarts, last_end = win
        if frozen is not self._frozen:
            self._after_cache.clear()
        self._tw, self._after, self._frozen, self.last_end = tw, after, frozen, last_end
        self.restarts += restarts
        self.restarts_total += restarts
        self._commit(k, y, u, f_next, post, abs(r1))

    def _propagate(self, v, ta, tb):
        """Phi(tb, ta) v across window ends.

        Returns (v, (window start, after, frozen gains, restarts, last end)).
        """
        tw, after, frozen, restarts, last_end = self._tw, self._after, self._frozen, 0, self.last_end
        t = ta
        while t < tb:
            if after:
                v = self._after_step(v, tb - t)
                break
            t_end = tw + self.s_end
            if tb < t_end - 1e-10:
                v = self.transition_window(v, t - tw, tb - tw)
                break
            # the window ends within (t, tb]: up to its end exactly, then what mode says
            if t_end - t > 1e-10:
                v = self.transition_window(v, t - tw, self.s_end)
            t = t_end
            last_end = (t_end, self.end_reason)
            if self.mode != "restart":
                after = True
                continue
            tw = t_end
            restarts += 1
            if not v.any() and tb - t > self.s_end:
                # nothing left to carry (a window that runs to T maps every error to 0):
                # skip the whole windows of a long step at once
                k = int((tb - t) // self.s_end)
                tw += k * self.s_end
                restarts += k
                t = tw
            if restarts > 100000:
                raise SampleRejected("step_spans_too_many_windows")
        return v, (tw, after, frozen, restarts, last_end)

    def _guard(self, t, h, win):
        """Sampling guard: end the window at t when fewer than 1/beta_guard steps of
        length h are left before T (the sampled output cannot feed a faster observer)."""
        tw, after, frozen, restarts, last_end = win
        if after or math.isinf(self.beta_guard):
            return win
        left = self.T - (t - tw)
        if left <= 0 or h < self.beta_guard * left:
            return win
        last_end = (t, "sampling limit")
        if self.mode == "restart":
            return (t, False, frozen, restarts + 1, last_end)
        if self.mode == "constant":
            frozen = self.gains_at(self.T / left).copy()
            if not np.all(hurwitz_roots(frozen).real < 0):
                frozen = None            # cannot freeze there: stop the injections instead
        return (tw, True, frozen, restarts, last_end)

    def _commit(self, k, y, u, f, post_residual, residual):
        """Store the accepted sample (model time k quanta); post_residual = y - x_hat_1."""
        t = k * STEP_QUANTUM
        self._t = t
        self._prev = (k, y, u, f, post_residual)
        self._residual = residual
        self._post = post_residual
        g = self._gains_now(t)                  # the preallocated buffer (or frozen/zeros)
        gmax = max(map(abs, g.tolist()))        # (faster than numpy for a few entries)
        self._health = abs(post_residual) * gmax
        if gmax > self._g_peak:
            self._g_peak = gmax
        self._x_pub = self._x if self.Smap is None else self.Smap @ self._x

    def _gains_now(self, t) -> np.ndarray:
        if self._after:
            return self._zeros if self._frozen is None else self._frozen
        s = t - self._tw
        return self.gains_at(self.T / (self.T - s)) if s < self.T else self._infs

    # -- outputs -------------------------------------------------------------------------
    @property
    def estimate(self):
        return self._x_pub

    @property
    def guaranteed_time(self):
        return self.T

    @property
    def health(self):
        return self._health

    @property
    def gains(self) -> np.ndarray:
        """g_1..g_n at the last sample (0 after the window in mode stop)."""
        return np.array(self._gains_now(self._t)) if self._t is not None else np.zeros(self.n)

    @property
    def injections(self) -> np.ndarray:
        """gamma_i = g_i (y - x_hat_1) at the last sample (Theorem 1: bounded)."""
        return self.gains * self._post

    @property
    def window_start(self) -> float:
        """Start of the current window (the stamps' time base)."""
        return self._clock_t0 + self._tw - self._kstart * STEP_QUANTUM

    @property
    def after_window(self) -> bool:
        return self._after

    def diagnostics(self):
        out = {
            "mode": self.mode,
            "prescribed time T (s)": f"{self.T:.6g}",
            "m": str(self.m),
            "window end (s after window start)": f"{self.s_end:.6g} ({self.end_reason})"
            + ("" if math.isinf(self.beta_guard) else
               f", or earlier at the sampling limit ({self.sampling_limit:g}: fewer than "
               f"{1.0 / self.beta_guard:.0f} samples left before T)"),
        }
        if self._t is None:
            return out
        s = self._t - self._tw
        if self._after:
            out["phase"] = ("after the window: injections off (open loop)" if self._frozen is None
                            else "after the window: constant gains")
            out["time to T (s)"] = "passed"
        else:
            out["phase"] = "in a window"
            out["time to T (s)"] = f"{self.T - s:.6g}"
        out["window started at (s)"] = f"{self.window_start:.6f}"
        if self.last_end is not None:
            out["last window end (s)"] = f"{self.window_start - self._tw + self.last_end[0]:.6f} ({self.last_end[1]})"
        out["restarts (since reset)"] = str(self.restarts)
        out["restarts (total)"] = str(self.restarts_total)
        out["largest gain now"] = f"{float(np.max(np.abs(self.gains))):.4g}"
        out["largest gain since reset"] = f"{self._g_peak:.4g}"
        out["gamma_i = g_i (y - x_hat_1)"] = ", ".join(f"{v:.4g}" for v in self.injections)
        out["largest |gamma_i| (health)"] = f"{self._health:.4g}"
        return out
