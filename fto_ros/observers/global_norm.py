"""Global observer with a state-norm estimator (Astolfi & Praly 2005, Sect. 5, eq. 79-85).

Plant in observability form (the paper's eq. 1-2), states x0 .. xn, y = x0::

    x0' = x1, ..., x_{n-1}' = xn,  xn' = f_n(x0, ..., xn)

globally completely observable and output-to-state stable: V' <= -V + gamma_1(x0) and
|x| <= gamma_2(V) (Assumption 1).  The observer (full-order form, eq. 85)::

    xh_i' = xh_{i+1} - k_i(w) (y - xh_0)            i = 0 .. n-1
    xh_n' = -k_n(w) (y - xh_0) + gh(w) sat(f_n(y, xh_1, .., xh_n) / gh(w))
    w'    = -w + gamma_1(y)                            (the state-norm estimator, eq. 11)

with k(w) from eq. (79): (I + L(w)) k = ((-a_0)^1, (-a_1)^2, ..., (-a_n)^(n+1)), L the
strictly lower triangular matrix with (i, j) entry (-a_i)^(i-j).  NOTE the sign: the
paper's k_i (eq. 79) are the entries of the error matrix of eq. (80), e_i' = k_i e_0 +
e_{i+1}, so k_0 = -a_0 < 0; eq. (85) writes "k_i (x0 - xh0)" with the opposite sign
convention.  We implement the error dynamics (80) exactly, i.e. the injection gains are
-k_i (k_0 = -a_0: the first gain is +a_0).  For n = 1 the frozen-w error matrix has the
eigenvalues -a_1 and -(a_0 - a_1).

The reduced-order form (eq. 83-84) is available as ``form: reduced``: chi' = (S + k e1')
chi + E_n v_n + (k_dot_i - k_{i+1} - k_i k_1) y, xh = chi - k y (k from a_1..a_n).  It is
discretised with the gains frozen over a step and chi re-based, chi = xh + k(w_mid) y, at
every step: within a frozen step k_dot = 0 and the gain change is carried exactly by the
re-basing (integrating chi across steps with a sampled k_dot loses ~1e-6 relative accuracy
to the cancellation in xh = chi - k y when k is large).

Numerics (linear parts integrated exactly, see docs/architecture.md): between two samples
the gains are frozen at the mid-step value of w (w itself is integrated exactly for gamma_1(y) linear
in time); the linear part x' = (S + k e0') x + G y(t) + E v(t) is then solved EXACTLY for
y(t) a polynomial (first-order hold, or the quadratic through the last three samples) and
v(t) linear, as x(h) = p(h) + exp(A h) (x(0) - p(0)), p the polynomial particular solution
(O(n) companion solves).  exp(A h) is closed form for n + 1 <= 2, from the eigenvalues
(Cardano + Newton polish for 3x3, numpy.roots beyond) otherwise, a Taylor series of the
balanced matrix when |lambda| h < 1/2, scipy.linalg.expm when eigenvalues cluster.  This is stable and exact in the linear part for ANY gain size (the
gains grow with w without bound); the model term v is a predictor-corrector (Heun) pair.
"""
from __future__ import annotations

import cmath
import math
import warnings
from typing import Sequence

import numpy as np
import sympy

from ..core.errors import ConfigNote
from ..core.expressions import NamedFunction, compile_exprs, parse
from .base import ConfigError, Observer, Param, SampleRejected

P = "global_norm."


# ---------------------------------------------------------------------------------------
# exact steps of x' = A x + r(t), A = S + c e0' (upper shift plus a first column c)
# ---------------------------------------------------------------------------------------
def companion_solve(c: Sequence[float], b: Sequence[float]) -> list[float]:
    """z with (S + c e0') z = b, O(m): rows i < m-1 read z_{i+1} + c_i z_0 = b_i."""
    m = len(c)
    z0 = b[m - 1] / c[m - 1]
    z = [z0] * m
    for i in range(m - 1):
        z[i + 1] = b[i] - c[i] * z0
    return z


def companion_char_roots(c: Sequence[float]) -> list[complex]:
    """Roots of det(sI - A) = s^m - c0 s^(m-1) - ... - c_{m-1}."""
    m = len(c)
    if m == 3:
        b, cc, d = -c[0], -c[1], -c[2]
        d0 = b * b - 3 * cc
        d1 = 2 * b ** 3 - 9 * b * cc + 27 * d
        sq = cmath.sqrt(d1 * d1 - 4 * d0 ** 3)
        big = (d1 + sq) if abs(d1 + sq) >= abs(d1 - sq) else (d1 - sq)
        if big == 0:
            return [complex(-b / 3)] * 3
        C = (big / 2) ** (1.0 / 3.0)
        xi = complex(-0.5, math.sqrt(3) / 2)
        roots = []
        for k in range(3):
            Ck = C * xi ** k
            lam = -(b + Ck + d0 / Ck) / 3
            for _ in range(2):                         # Newton polish
                p = ((lam + b) * lam + cc) * lam + d
                dp = (3 * lam + 2 * b) * lam + cc
                if dp == 0:
                    break
                lam -= p / dp
            roots.append(lam)
        return roots
    return [complex(r) for r in np.roots([1.0] + [-float(v) for v in c])]


def companion_expm(c: Sequence[float], h: float) -> list[list[float]]:
    """exp((S + c e0') h) as nested lists, exact (closed form / spectral / scipy)."""
    m = len(c)
    if m == 1:
        return [[math.exp(c[0] * h)]]
    if m == 2:
        # A = [[c0, 1], [c1, 0]]: e^{Ah} = e^{mu h} (C I + S (A - mu I)), mu = c0/2
        mu = 0.5 * c[0]
        om2 = mu * mu + c[1]
        if om2 > 0:
            om = math.sqrt(om2)
            if om * h < 1.0:
                e = math.exp(mu * h)
                Cf, Sf = e * math.cosh(om * h), e * math.sinh(om * h) / om
            else:
                ep, em = math.exp((mu + om) * h), math.exp((mu - om) * h)
                Cf, Sf = 0.5 * (ep + em), 0.5 * (ep - em) / om
        elif om2 < 0:
            om = math.sqrt(-om2)
            e = math.exp(mu * h)
            Cf, Sf = e * math.cos(om * h), e * math.sin(om * h) / om
        else:
            e = math.exp(mu * h)
            Cf, Sf = e, e * h
        return [[Cf + Sf * (c[0] - mu), Sf], [Sf * c[1], Cf - Sf * mu]]
    roots = companion_char_roots(c)
    scale = max(abs(r) for r in roots) or 1.0
    if scale * h < 0.5:
        return _expm_taylor(c, h, scale)
    sep = min(abs(roots[i] - roots[j]) for i in range(m) for j in range(i))
    if sep < 1e-3 * scale or not all(cmath.isfinite(r) for r in roots):
        return _expm_scipy(c, h)
    E = [[0.0] * m for _ in range(m)]
    for lam in roots:
        # right eigenvector r: r0 = 1, r_{i+1} = lam r_i - c_i; left l_j = lam^(m-1-j); l.r = p'(lam)
        r = [1.0 + 0j] * m
        for i in range(m - 1):
            r[i + 1] = lam * r[i] - c[i]
        dp = m * lam ** (m - 1) - sum((m - 1 - i) * c[i] * lam ** (m - 2 - i) for i in range(m - 1))
        coef = cmath.exp(lam * h) / dp
        lpow = [lam ** (m - 1 - j) for j in range(m)]
        for i in range(m):
            ri = coef * r[i]
            row = E[i]
            for j in range(m):
                row[j] += (ri * lpow[j]).real
    return E


def _expm_taylor(c, h, s):
    """exp(A h) by a 16-term Taylor series of the balanced matrix (||A h|| small: no cancellation
    of the spectral sum).  D^-1 A D = s (S + c_i / s^(i+1) e0'), D = diag(s^i)."""
    m = len(c)
    B = [[0.0] * m for _ in range(m)]
    sh = s * h
    for i in range(m):
        B[i][0] += c[i] / s ** (i + 1) * sh
        if i + 1 < m:
            B[i][i + 1] += sh
    E = [[float(i == j) for j in range(m)] for i in range(m)]
    for k in range(16, 0, -1):                    # Horner: E = I + B/k E
        E = [[float(i == j) + sum(B[i][l] * E[l][j] for l in range(m)) / k for j in range(m)]
             for i in range(m)]
    return [[E[i][j] * s ** (i - j) for j in range(m)] for i in range(m)]


def _expm_scipy(c: Sequence[float], h: float) -> list[list[float]]:
    from scipy.linalg import expm
    m = len(c)
    A = np.diag(np.ones(m - 1), 1)
    A[:, 0] += np.asarray(c, dtype=float)
    return expm(A * h).tolist()


def companion_step(c, E, x, h, r0, r1, r2):
    """x(h) for x' = (S + c e0') x + r0 + r1 t + r2 t^2, exactly, given E = exp(A h).

    Particular solution p(t) = P + Q t + R t^2: A R = -r2, A Q = 2 R - r1, A P = Q - r0.
    """
    m = len(c)
    R = companion_solve(c, [-v for v in r2])
    Q = companion_solve(c, [2.0 * R[i] - r1[i] for i in range(m)])
    Pp = companion_solve(c, [Q[i] - r0[i] for i in range(m)])
    d = [x[i] - Pp[i] for i in range(m)]
    out = []
    for i in range(m):
        row = E[i]
        acc = Pp[i] + (Q[i] + R[i] * h) * h
        for j in range(m):
            acc += row[j] * d[j]
        out.append(acc)
    return out


def output_polynomial(y_prev2, h_prev, y0, y1, h, quadratic):
    """(a, b, c) with y(s) = a + b s + c s^2 on [0, h] through y0, y1 (and y_prev2 at -h_prev)."""
    s = (y1 - y0) / h
    if quadratic and y_prev2 is not None:
        kap = (y_prev2 - y0 + s * h_prev) / (h_prev * (h_prev + h))
        return y0, s - kap * h, kap
    return y0, s, 0.0


def norm_estimator_step(w0, g0, g1, h):
    """w(h) for w' = -w + gamma_1, gamma_1 linear from g0 to g1 over [0, h] (exact)."""
    em1 = -math.expm1(-h)                  # 1 - e^{-h}
    return (1.0 - em1) * w0 + g0 * em1 + (g1 - g0) * (h - em1) / h


# ---------------------------------------------------------------------------------------
# gains from eq. (79)
# ---------------------------------------------------------------------------------------
def gain_exprs(a: Sequence[sympy.Expr]) -> list[sympy.Expr]:
    """k = (I + L)^{-1} ((-a_1)^1, ..., (-a_m)^m) for the list a (eq. 79, forward substitution)."""
    m = len(a)
    k: list[sympy.Expr] = []
    for i in range(m):
        rhs = (-a[i]) ** (i + 1)
        for j in range(i):
            rhs -= (-a[i]) ** (i - j) * k[j]
        k.append(rhs)
    return k


def gains_numeric(a: Sequence[float]) -> np.ndarray:
    m = len(a)
    IL = np.eye(m)
    for i in range(m):
        for j in range(i):
            IL[i, j] = (-a[i]) ** (i - j)
    v = np.array([(-a[i]) ** (i + 1) for i in range(m)])
    return np.linalg.solve(IL, v), IL


def _default_c(dim: int) -> list[float]:
    """c_i for a_i = c_i gamma_hat (dim gains): the last 6 (footnote 6: > 11/2), the one before
    1.05 (2 (dim-1) 6^2 + 3.5), i.e. the necessary part of (61) with gamma_hat -> infinity
    (80 for dim = 2: a_0 > (2 c_1^2 + 3/2 + 2/gh^2) gh = 75.5 gh), earlier ones twice the sum
    of the later ones (frozen error matrix Hurwitz).  For dim >= 3 no constant c_0 satisfies
    (61) for all w (mu_0 grows like gamma_hat^2): the start-up check says so.
    """
    if dim == 1:
        return [6.0]
    c = [float(math.ceil(1.05 * (2 * (dim - 1) * 36.0 + 3.5))), 6.0]
    while len(c) < dim:
        c.insert(0, 2.0 * sum(c))
    return c


class GlobalNormObserver(Observer):
    TYPE = "global_norm"
    DESCRIPTION = ("Astolfi-Praly global observer with a state-norm estimator: converges on the "
                   "whole domain of existence, even with unbounded / escaping trajectories")
    HEALTH_NAME = "gamma_hat(w), the scale of the gains"
    PARAMS = (
        Param("n_states", "int", 2, "number of states x0 .. xn (n + 1 in the paper's notation)",
              min=2, max=6),
        Param("form", "string", "full", "full-order observer (eq. 85) or reduced-order (eq. 83-84)",
              choices=("full", "reduced")),
        Param("f", "string", None, "f_n(y, x1, .., xn, u0, ..): the last state's derivative, y "
              "standing for x0, u0.. the known inputs, e.g. '-x1 + y**3 + u0'"),
        Param("n_inputs", "int", 0, "number of known inputs u0.. in f (held between samples)",
              min=0, max=32),
        Param("gamma_1", "string", "y**2", "gamma_1(y) >= 0 of the norm estimator w' = -w + "
              "gamma_1(y) (Assumption 1: V' <= -V + gamma_1(x0))"),
        Param("gamma_hat", "string", "1 + w", "gamma_hat(w) >= 1, nondecreasing, >= gamma(4w+2) "
              "(eq. 19): the bound on |x| + |f_n| + Lipschitz of f_n; saturation level and gain scale"),
        Param("a", "string_array", [], "a_0(w) .. a_n(w) (n_states expressions in w; the reduced "
              "form ignores a_0); empty: a_i = c_i gamma_hat(w)"),
        Param("c", "double_array", [], "c_0 .. c_n for the default a_i = c_i gamma_hat(w) "
              "(empty: (80, 6) for n_states = 2, footnote 6)", min=0.0),
        Param("w0", "double", 1.0, "initial value of the norm estimator w (> 0 in the paper)",
              min=0.0),
        Param("output_hold", "string", "quadratic", "y between samples: 'foh' (linear) or "
              "'quadratic' (through the last three samples)", choices=("foh", "quadratic")),
        Param("conditions", "string", "refuse", "footnote-6 inequalities violated on the check "
              "grid: refuse the parameters or only warn", choices=("refuse", "warn")),
        Param("check_w_max", "double", 1.0e6, "the conditions on a_i, gamma_hat are checked "
              "for w on a log grid in [0, check_w_max]", min=1.0),
        Param("check_y_max", "double", 1.0e3, "gamma_1(y) >= 0 is checked for |y| <= check_y_max",
              min=0.0),
        Param("state_names", "string_array", [], "names of the states (empty: x0, x1, ...)"),
    )

    def __init__(self, cfg: dict):
        m = cfg["n_states"]
        n = m - 1
        self.n_states, self.n_outputs, self.n_inputs = m, 1, cfg["n_inputs"]
        self.reduced = cfg["form"] == "reduced"
        self.quadratic = cfg["output_hold"] == "quadratic"
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(m)]
        if len(self.state_names) != m:
            raise ConfigError(P + "state_names", f"expected {m} names, got {len(self.state_names)}")
        if cfg["f"] is None:
            raise ConfigError(P + "f", "required: f_n(y, x1, .., xn), e.g. '-x1 + y**3'")
        xnames = [f"x{i}" for i in range(1, m)]
        self.f = NamedFunction([cfg["f"]], ["y"] + xnames + [f"u{j}" for j in range(self.n_inputs)],
                               P + "f")
        self._u = (0.0,) * self.n_inputs        # the input held over the current step
        self.gamma_1 = NamedFunction([cfg["gamma_1"]], ["y"], P + "gamma_1")
        wsym = sympy.Symbol("w", real=True)
        gh = parse(cfg["gamma_hat"], [wsym], P + "gamma_hat")
        if cfg["a"]:
            if len(cfg["a"]) != m:
                raise ConfigError(P + "a", f"expected {m} expressions a_0(w) .. a_{n}(w), "
                                  f"got {len(cfg['a'])}")
            a = [parse(t, [wsym], f"{P}a[{i}]") for i, t in enumerate(cfg["a"])]
            self.c = None
        else:
            c = cfg["c"] or ([1.0] if self.reduced else []) + _default_c(m - 1 if self.reduced else m)
            if len(c) != m:
                raise ConfigError(P + "c", f"expected {m} values c_0 .. c_{n}, got {len(c)}")
            if any(v <= 0 for v in c):
                raise ConfigError(P + "c", f"all c_i must be > 0, got {c}")
            self.c = list(c)
            a = [sympy.Float(ci) * gh for ci in c]
        self.a_exprs, self.gh_expr = a, gh
        used = a[1:] if self.reduced else a
        k = gain_exprs(used)
        outs = [gh] + list(a) + k
        self._gains = compile_exprs(outs, [wsym])
        self._dim = len(used)
        self.w0 = cfg["w0"]
        self.warnings: list[str] = []
        self._check_conditions(cfg)
        self._xhat = [0.0] * m
        self._w = self.w0
        self._y = self._yprev = self._hprev = None
        self._residual = float("nan")
        self._sat_active = False
        self._sat_count = 0
        self._steps = 0
        self._last = None

    # -- parameter checks ------------------------------------------------------------
    def _eval(self, w):
        try:
            vals = self._gains(float(w))
        except (ValueError, OverflowError, ZeroDivisionError):
            return None
        return vals if all(math.isfinite(v) for v in vals) else None

    def _check_conditions(self, cfg):
        m, dim = self.n_states, self._dim
        grid = np.concatenate(([0.0], np.logspace(-3, math.log10(cfg["check_w_max"]), 160)))
        soft: list[str] = []
        flagged: set[int] = set()
        prev_gh = None
        for w in grid:
            vals = self._eval(w)
            if vals is None:
                raise ConfigError(P + "gamma_hat", f"gamma_hat or a_i(w) is not finite at w = {w:.4g}")
            gh = vals[0]
            a = vals[1:1 + m]
            k = vals[1 + m:1 + m + dim]
            if gh < 1.0 - 1e-12:
                raise ConfigError(P + "gamma_hat", f"must be >= 1 (eq. 5, 19); gamma_hat({w:.4g}) = {gh:.4g}")
            if prev_gh is not None and gh < prev_gh * (1 - 1e-12):
                raise ConfigError(P + "gamma_hat", f"must be nondecreasing; it decreases near w = {w:.4g}")
            prev_gh = gh
            used = a[1:] if self.reduced else a
            for i, ai in enumerate(a):
                if ai <= 0 and (i > 0 or not self.reduced):
                    raise ConfigError(P + ("a" if self.c is None else "c"),
                                      f"a_{i}(w) must be > 0; a_{i}({w:.4g}) = {ai:.4g}")
            A = np.diag(np.ones(dim - 1), 1) if dim > 1 else np.zeros((1, 1))
            A[:, 0] += k
            eig = np.linalg.eigvals(A)
            if np.max(eig.real) >= 0:
                raise ConfigError(P + ("a" if self.c is None else "c"),
                                  f"the frozen error matrix of eq. (80) is not Hurwitz at w = {w:.4g} "
                                  f"(eigenvalues {np.round(eig, 4).tolist()}); e.g. n_states = 2 needs "
                                  "a_0 > a_1 > 0")
            # footnote 6: a_last > 11/2 gh; a_j > ((mu_j^2 / gh^2 + 3) / 2) gh (the part of (61)
            # without the c_2jw, c_j0 terms, which are >= 0: a NECESSARY condition)
            off = 1 if self.reduced else 0
            if used[-1] <= 5.5 * gh and dim - 1 not in flagged:
                flagged.add(dim - 1)
                soft.append(f"a_{dim - 1 + off}(w) > 11/2 gamma_hat(w) fails at w = {w:.4g} "
                            f"({used[-1]:.4g} <= {5.5 * gh:.4g})")
            _, IL = gains_numeric(used)
            ell = np.linalg.inv(IL)
            for j in range(dim - 1):
                mu2 = 4.0 * (1.0 + sum(i * ell[i, j] ** 2 for i in range(j + 1, dim)))
                bound = (mu2 / gh ** 2 + 3.0) / 2.0 * gh
                if used[j] <= bound and j not in flagged:
                    flagged.add(j)
                    soft.append(f"a_{j + off}(w) > ((mu_{j + off}^2/gamma_hat^2 + 3)/2) gamma_hat "
                                f"(footnote 6, eq. 61 without its c_2jw, c_j0 terms) fails at "
                                f"w = {w:.4g} ({used[j]:.4g} <= {bound:.4g})")
        for y in np.concatenate((-np.logspace(-3, math.log10(max(cfg["check_y_max"], 1e-3)), 60),
                                 [0.0], np.logspace(-3, math.log10(max(cfg["check_y_max"], 1e-3)), 60))):
            g = self.gamma_1(float(y))[0]
            if not (g >= 0.0) and not math.isinf(g):
                raise ConfigError(P + "gamma_1", f"must be >= 0 (Assumption 1); gamma_1({y:.4g}) = {g:.4g}")
        if soft:
            name = P + ("a" if self.c is None else "c")
            msg = "; ".join(soft)
            if cfg["conditions"] == "refuse":
                raise ConfigError(name, msg + f" (set {P}conditions: warn to run anyway)")
            warnings.warn(f"{name}: {msg}", ConfigNote, stacklevel=3)
            self.warnings = soft

    # -- protocol --------------------------------------------------------------------
    def _restart(self, x0_hat):
        m = self.n_states
        self._xhat = [0.0] * m if x0_hat is None else [float(v) for v in x0_hat]
        self._w = self.w0
        self._y = self._yprev = self._hprev = None
        self._sat_count = 0
        self._steps = 0

    def _vals(self, w):
        vals = self._gains(w)
        m, dim = self.n_states, self._dim
        gh = vals[0]
        k = vals[1 + m:1 + m + dim]
        return gh, vals[1:1 + m], k, None

    def _model(self, y, xbar, gh):
        try:
            fv = self.f(y, *xbar, *self._u)[0]
        except OverflowError:
            fv = float("nan")
        if fv != fv:
            raise SampleRejected("non_finite_model_term")
        if fv > gh:
            return gh, True
        if fv < -gh:
            return -gh, True
        return fv, False

    def _first(self, y, u, gap):
        yk = float(y[0])
        try:
            gh, a, k, dk = self._vals(self._w)
        except (ValueError, OverflowError, ZeroDivisionError):
            raise SampleRejected("non_finite_gain") from None
        if self.reduced:
            self._xhat = [yk] + self._xhat[1:]
        self._y, self._g1 = yk, self.gamma_1(yk)[0]
        self._gh, self._k = gh, k
        self._residual = abs(yk - self._xhat[0])
        self._u = tuple(u)

    def _step(self, s, h, y, u):
        yk = float(y[0])
        try:
            new = self._advance(h, yk)
        except (ValueError, OverflowError, ZeroDivisionError):
            raise SampleRejected("non_finite_estimate") from None
        x, xhat, w1, g1b, gh1, k1, sat, resid = new
        if not all(math.isfinite(v) for v in xhat) or not math.isfinite(w1):
            raise SampleRejected("non_finite_estimate")
        self._xhat, self._w, self._g1 = xhat, w1, g1b
        self._gh, self._k = gh1, k1
        self._sat_active = sat
        self._sat_count += sat
        self._steps += 1
        self._yprev, self._hprev = self._y, h
        self._y = yk
        self._residual = resid
        self._u = tuple(u)

    def _advance(self, h, yk):
        m = self.n_states
        y0 = self._y
        ya, yb, yc = output_polynomial(self._yprev, self._hprev, y0, yk, h, self.quadratic)
        g1a = self._g1
        g1b = self.gamma_1(yk)[0]
        if not math.isfinite(g1b):
            raise SampleRejected("non_finite_gamma_1")
        w0 = self._w
        w1 = norm_estimator_step(w0, g1a, g1b, h)
        wm = 0.5 * (w0 + w1)
        gh0 = self._gh
        ghm, _, k, dk = self._vals(wm)
        gh1, _, k1, _ = self._vals(w1)
        E = companion_expm(k, h)
        xbar0 = self._xhat[1:]
        if self.reduced:
            # eq. (83) in chi = xh + k y, re-based at every step with the frozen k = k(w_mid):
            # within a frozen-gain step k_dot = 0, and the change of k between steps is carried
            # exactly by the re-basing (no k_dot, no cancellation between chi and k y)
            dim = m - 1
            G = [-(k[i + 1] if i + 1 < dim else 0.0) - k[i] * k[0] for i in range(dim)]
            xs = [xbar0[i] + k[i] * y0 for i in range(dim)]
        else:
            dim = m
            G = [-ki for ki in k]
            xs = self._xhat
        v0, _ = self._model(y0, xbar0, gh0)
        r0 = [G[i] * ya for i in range(dim)]
        r1 = [G[i] * yb for i in range(dim)]
        r2 = [G[i] * yc for i in range(dim)]
        r0[-1] += v0
        xp = companion_step(k, E, xs, h, r0, r1, r2)
        if self.reduced:
            xbar1 = [xp[i] - k[i] * yk for i in range(dim)]
        else:
            xbar1 = xp[1:]
        v1, _ = self._model(yk, xbar1, gh1)
        r1[-1] += (v1 - v0) / h
        x = companion_step(k, E, xs, h, r0, r1, r2)
        if self.reduced:
            xhat = [yk] + [x[i] - k[i] * yk for i in range(dim)]
            resid = 0.0
        else:
            xhat = x
            resid = abs(yk - x[0])
        _, sat = self._model(yk, xhat[1:], gh1)
        return xhat, xhat, w1, g1b, gh1, k1, sat, resid

    # -- outputs ---------------------------------------------------------------------
    @property
    def estimate(self):
        return np.array(self._xhat, dtype=float)

    @property
    def w(self) -> float:
        """The norm estimator's state."""
        return self._w

    @property
    def gamma_hat(self) -> float:
        return self._gh if self.started else self._vals(self._w)[0]

    @property
    def injection_gains(self) -> list[float]:
        """The gains multiplying (y - xh_0) in eq. (85), i.e. -k_i(w) (full form), or k_i(w)."""
        k = self._k if self.started else self._vals(self._w)[2]
        return [-v for v in k] if not self.reduced else list(k)

    @property
    def health(self):
        return float(self.gamma_hat)

    def diagnostics(self):
        out = {
            "form": "full-order (eq. 85)" if not self.reduced else "reduced-order (eq. 83-84)",
            "w (norm estimator)": f"{self._w:.6g}",
            "gamma_hat(w)": f"{self.gamma_hat:.6g}",
            "gains": ", ".join(f"{g:.4g}" for g in self.injection_gains),
            "saturation active": "yes" if self._sat_active else "no",
            "saturated steps": f"{self._sat_count} of {self._steps}",
            "guarantee": "asymptotic, global (Theorem 3): error -> 0 as t -> escape time or infinity",
        }
        if self.warnings:
            out["conditions"] = "WARN: " + "; ".join(self.warnings)
        else:
            out["conditions"] = "footnote-6 checks passed on the grid"
        return out
