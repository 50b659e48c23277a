"""Finite-time observer in the original coordinates (Possieri, Vidano & Novara 2020).

Plant x' = f(x, u), y = h(x, u) (single output), written as text in the params file
(``states``, ``inputs``, ``f``, ``h``, ``constants``); the observability map O_(n-1)
(eq. 2-3), its Jacobian J = dO/dx and the input feed-forward G = dO/du_e u_e^(1,n)
are derived with sympy and compiled at start-up (core/symbolic_model.py).

``variant: filtered`` -- the 2n-dimensional observer (11):

    eta = (eta_0..eta_n): Levant's differentiator of order n on y (11a-11f), L bounding
          |y^(n+1)|, with the proper discretisation of core/differentiator.py;
    x_hat' = J^-1(x_hat, u_e) ( mu |eta~|^alpha sign(eta~) + eta^(1,n) - G(x_hat, u_e) )   (11g)
    eta~  = eta^(0,n-1) - O(x_hat, u_e)                                                   (11h)

  u_e: the input's derivatives, known (extra input channels) or estimated by a second
  differentiator of order ``input_order`` with Lipschitz constant Z (Remark 5, eq. 19-20);
  delayed start x_hat' = 0 for t - t0 < ``delay`` (Remark 2, eq. 15); optional linear
  filter Q(s) on every eta_i before the inversion (Remark 6; e.g. the paper's notch
  (s^2 + 50^2)/(s^2 + 5 s + 50^2)).

``variant: n_dimensional`` -- the n-dimensional observer (21): a differentiator of order
  n - 1 on y whose state is O(x_hat, u_e) itself (started at O(x_hat(0), u_e(0))), so x_hat
  follows xi = O(x_hat, u_e) exactly; no filtering possible (the paper's comparison).

Discretisation (sample-driven, variable step h): per sample the differentiators are
updated first, then (11g) is split into its non-stiff feed-forward part (trapezoid on
eta^(1,n), explicit on G) and its stiff finite-time part d(eta~)/dt = -mu |eta~|^alpha
sign(eta~) (eta and u_e frozen at the new sample), which is integrated by backward Euler:
eta~+ = soft-threshold(eta~, tau), tau = h mu |eta~+|^alpha (a scalar root, no
chattering, unconditionally stable, eta~ = 0 is an exact equilibrium), and mapped back
to x_hat by one Newton step with J at the predicted point.  Transactional: the
differentiators' states are snapshotted and restored when a sample is rejected.

No guaranteed time is published (the base class's inf): Theorem 2 / Corollary 1 make the
convergence time finite, but T* depends on constants (M, N, S) that are not computable
from the model in general.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.differentiator import SCHEMES, Differentiator, recursive_to_nonrecursive
from ..core.discretize import MAX_SUBSTEPS, ExactStepper
from ..core.symbolic_model import SymbolicModel
from .base import ConfigError, Observer, Param, SampleRejected

P = "newton_inversion."


# ----------------------------------------------------------------------------- numerics
def implicit_flow(e: list[float], c: float, alpha: float) -> list[float]:
    """Backward-Euler step of e' = -mu |e|_2^alpha sign(e) (entry-wise sign), c = h mu.

    e+ = sign(e) max(|e| - tau, 0) with tau = c |e+|_2^alpha: the unique root of the
    increasing phi(tau) = tau - c R(tau)^alpha, R(tau) = |(|e| - tau)_+|_2, on
    [0, min(c |e|^alpha, max|e|)] (safeguarded Newton).
    """
    a = [abs(v) for v in e]
    amax = max(a)
    if amax == 0.0:
        return [0.0] * len(e)

    def R(tau):
        s = 0.0
        s1 = 0.0
        for ai in a:
            d = ai - tau
            if d > 0.0:
                s += d * d
                s1 += d
        return math.sqrt(s), s1

    r0, _ = R(0.0)
    hi = min(c * r0 ** alpha, amax)
    # root within 1e-12 of amax: e+ is zero to 1e-12 relative, return it exactly
    t_test = amax * (1.0 - 1e-12)
    if t_test - c * R(t_test)[0] ** alpha <= 0.0:
        return [0.0] * len(e)
    hi = min(hi, t_test)
    lo = 0.0
    tau = hi
    for _ in range(60):
        r, s1 = R(tau)
        if r <= 0.0:
            phi, dphi = tau, math.inf
        else:
            phi = tau - c * r ** alpha
            dphi = 1.0 + c * alpha * r ** (alpha - 2.0) * s1
        if phi > 0.0:
            hi = tau
        else:
            lo = tau
        if abs(phi) <= 1e-15 * max(tau, 1e-300) or hi - lo <= 1e-15 * hi:
            break
        nxt = tau - phi / dphi if dphi < math.inf else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        tau = nxt
    return [math.copysign(max(ai - tau, 0.0), v) for ai, v in zip(a, e)]


def solve(J: tuple | list, b: list[float], n: int) -> list[float] | None:
    """J (row-major, n x n) \\ b; closed form for n <= 3, numpy otherwise; None if singular."""
    if n == 1:
        d = J[0]
        return None if d == 0.0 else [b[0] / d]
    if n == 2:
        a, bb, c, d = J
        det = a * d - bb * c
        scale = (abs(a) + abs(bb)) * (abs(c) + abs(d))
        if not abs(det) > 1e-13 * scale:
            return None
        return [(d * b[0] - bb * b[1]) / det, (a * b[1] - c * b[0]) / det]
    if n == 3:
        a, bb, c, d, e, f, g, hh, i = J
        A = e * i - f * hh
        B = f * g - d * i
        C = d * hh - e * g
        det = a * A + bb * B + c * C
        scale = ((abs(a) + abs(bb) + abs(c)) * (abs(d) + abs(e) + abs(f))
                 * (abs(g) + abs(hh) + abs(i)))
        if not abs(det) > 1e-13 * scale:
            return None
        y0, y1, y2 = b
        return [(A * y0 + (c * hh - bb * i) * y1 + (bb * f - c * e) * y2) / det,
                (B * y0 + (a * i - c * g) * y1 + (c * d - a * f) * y2) / det,
                (C * y0 + (bb * g - a * hh) * y1 + (a * e - bb * d) * y2) / det]
    M = np.asarray(J, dtype=float).reshape(n, n)
    if np.linalg.cond(M) > 1e13:
        return None
    return np.linalg.solve(M, np.asarray(b, dtype=float)).tolist()


class LinearFilter:
    """Q(s) = num(s)/den(s) (proper) on `channels` signals, exact first-order-hold step."""

    def __init__(self, num, den, channels: int, parameter: str):
        num = [float(v) for v in num]
        den = [float(v) for v in den]
        while num and num[0] == 0.0:
            num.pop(0)
        if not den or den[0] == 0.0:
            raise ConfigError(parameter + "filter_denominator", "needs a nonzero leading coefficient")
        if len(num) > len(den):
            raise ConfigError(parameter + "filter_numerator", f"Q(s) must be proper: numerator "
                              f"degree {len(num) - 1} > denominator degree {len(den) - 1}")
        k = len(den) - 1
        a = np.array(den) / den[0]
        b = np.zeros(k + 1)
        b[k + 1 - len(num):] = np.array(num) / den[0]
        roots = np.roots(a) if k else np.zeros(0)
        if k and np.max(roots.real) >= 0:
            raise ConfigError(parameter + "filter_denominator", f"Q(s) must be stable; poles "
                              f"{', '.join(f'{r:.4g}' for r in roots)}")
        self.k, self.channels = k, channels
        self.D = b[0]
        if k:
            # controllable canonical form
            A = np.zeros((k, k))
            A[:-1, 1:] = np.eye(k - 1)
            A[-1, :] = -a[1:][::-1]
            B = np.zeros((k, 1))
            B[-1, 0] = 1.0
            C = (b[1:] - b[0] * a[1:])[::-1].reshape(1, k)
            self.A, self.B, self.C = A, B, C
            self.stepper = ExactStepper(A, B)
            self.dc_state = -np.linalg.solve(A, B)          # state for a unit constant input
        self.dc_gain = float(np.polyval(num, 0.0) / np.polyval(den, 0.0)) if den[-1] != 0 else math.nan

    def start(self, w: np.ndarray) -> np.ndarray:
        """Filter state at rest for the constant input w (channels,)."""
        if not self.k:
            return np.zeros((0, self.channels))
        return self.dc_state @ w.reshape(1, -1)

    def step(self, X: np.ndarray, w0: np.ndarray, w1: np.ndarray, h: float):
        """(new state, output at the new sample) for inputs linear from w0 to w1."""
        if not self.k:
            return X, self.D * w1
        M = self.stepper.stacked(h)
        k = self.k
        Xn = M[:, :k] @ X + M[:, k:k + 1] @ w0.reshape(1, -1) + M[:, k + 1:] @ w1.reshape(1, -1)
        return Xn, (self.C @ Xn).ravel() + self.D * w1


# ----------------------------------------------------------------------------- observer
class NewtonInversionObserver(Observer):
    TYPE = "newton_inversion"
    DESCRIPTION = ("Possieri, Vidano & Novara 2020: sliding-mode differentiator + finite-time "
                   "Newton-like inversion of the observability map, in the plant's coordinates")
    HEALTH_NAME = "cond(J), condition number of the observability map's Jacobian at the estimate"
    PARAMS = (
        Param("states", "string_array", None, "state names, e.g. [q, q_dot, current] (n = length)"),
        Param("inputs", "string_array", [], "known input names, e.g. [V] (m = length; [] for none)"),
        Param("constants", "string_array", [], "named constants 'name=value' usable in f and h, "
              "e.g. ['a1=35', 'b1=15']; a value may use the constants before it"),
        Param("f", "string_array", None, "x' = f(x, u): one expression per state in the state, "
              "input and constant names (sin, cos, exp, sqrt, ... allowed)"),
        Param("h", "string_array", None, "y = h(x, u): one expression (single output)"),
        Param("variant", "string", "filtered", "'filtered': the 2n-dimensional observer (11) "
              "(optionally filtered, Remark 6); 'n_dimensional': the observer (21), for comparison",
              choices=("filtered", "n_dimensional")),
        Param("L", "double", 100.0, "differentiator constant: bound on |y^(n+1)| (filtered) or "
              "|y^(n)| (n_dimensional)", min=1e-9, read_only=False),
        Param("scheme", "string", "eigenvalue_matched", "differentiator discretisation "
              "(core/differentiator.py)", choices=SCHEMES, read_only=False),
        Param("rho", "double", 2.0, "eigenvalue_matched scheme: pole factor r = rho L^(1/(order+1))",
              min=1e-3, max=100.0, read_only=False),
        Param("lambdas", "double_array", [], "livne_levant/euler schemes: the paper's recursive "
              "gains lambda_0..lambda_order (e.g. [1.1, 1.5, 3] for n = 2); [] = Levant's "
              "(1.1, 1.5, 2, 3, 5, ...)", min=0.0, read_only=False),
        Param("max_step", "double", 0.0, "differentiator sub-step (s) for long sample gaps "
              "(0: none; the explicit schemes may need it)", min=0.0, read_only=False),
        Param("mu", "double", 10.0, "gain mu of the finite-time inversion (11g), > 0", min=0.0,
              read_only=False),
        Param("alpha", "double", 0.1, "exponent alpha in (0, 1) of (11g)", min=0.0, max=1.0,
              read_only=False),
        Param("input_derivatives", "string", "estimate", "'estimate': a differentiator of order "
              "input_order with constant Z on each input (Remark 5); 'known': the input vector "
              "carries every input followed by its derivatives 1..n "
              "([u0, u0', ..., u0^(n), u1, ...], m (n + 1) channels)",
              choices=("estimate", "known")),
        Param("input_order", "int", 0, "order of the input differentiator (0: n, the paper's "
              "choice); must reach the highest input derivative the map needs", min=0, max=7),
        Param("Z", "double", 1000.0, "input differentiator constant: bound on |u^(order+1)|",
              min=1e-9, read_only=False),
        Param("delay", "double", 0.0, "Remark 2: the inversion starts this long (s) after the "
              "first sample (x_hat held before), while the differentiators converge", min=0.0,
              read_only=False),
        Param("filter_numerator", "double_array", [], "Remark 6: numerator of Q(s), highest "
              "power first (e.g. [1, 0, 2500]); [] = no filter", read_only=False),
        Param("filter_denominator", "double_array", [], "Remark 6: denominator of Q(s), highest "
              "power first (e.g. [1, 5, 2500]); stable", read_only=False),
        Param("initial_estimate", "double_array", [], "x_hat(0) (n values; [] = zeros) where the "
              "start-up check runs; observer.initial_estimate, when set, overrides it at reset"),
        Param("check_box", "double_array", [], "start-up check of J over a box of states: "
              "[lo, hi] per state (2 n values; [] = only at x_hat(0))"),
        Param("check_input_box", "double_array", [], "with check_box: [lo, hi] per input, "
              "applied to the input and each derivative J depends on (the paper's |u_e| <= 10)"),
        Param("check_grid", "int", 9, "grid points per box dimension for the start-up check",
              min=2, max=101),
        Param("max_condition", "double", 1e8, "refuse the model when cond(J) exceeds this at "
              "x_hat(0) or over the box", min=1.0),
    )

    def __init__(self, cfg: dict):
        model = SymbolicModel(cfg["states"], cfg["inputs"], cfg["f"], cfg["h"],
                              cfg["constants"], prefix=P)
        self.model = model
        n, m = model.n, model.m
        self.n = n
        self.n_states, self.n_outputs = n, 1
        self.known_derivatives = cfg["input_derivatives"] == "known"
        self.n_inputs = m * (n + 1) if self.known_derivatives else m
        self.state_names = list(cfg["states"])
        self.ndim = cfg["variant"] == "n_dimensional"
        self.mu, self.alpha = cfg["mu"], cfg["alpha"]
        if not self.mu > 0:
            raise ConfigError(P + "mu", f"must be > 0, got {self.mu}")
        if not 0 < self.alpha < 1:
            raise ConfigError(P + "alpha", f"must be in (0, 1), got {self.alpha}")
        self.delay = cfg["delay"]
        order = n - 1 if self.ndim else n
        if self.ndim and n < 2:
            raise ConfigError(P + "variant", "n_dimensional needs n >= 2 (a differentiator of "
                              "order n - 1 >= 1)")
        if self.ndim and self.delay > 0:
            raise ConfigError(P + "delay", "the delayed start (Remark 2) belongs to the filtered "
                              "observer (11), not to the n_dimensional variant (21)")
        has_filter = bool(cfg["filter_numerator"] or cfg["filter_denominator"])
        if has_filter and self.ndim:
            raise ConfigError(P + "filter_numerator", "filtering the derivative estimates "
                              "(Remark 6) applies to variant 'filtered' only")
        if has_filter and not (cfg["filter_numerator"] and cfg["filter_denominator"]):
            raise ConfigError(P + "filter_denominator", "give both filter_numerator and "
                              "filter_denominator (or neither)")
        self.filter = (LinearFilter(cfg["filter_numerator"], cfg["filter_denominator"],
                                    order + 1, P) if has_filter else None)
        self.diff_args = self._differentiator_args(cfg, order, cfg["L"], "L", 1)
        self.Dy = Differentiator(**self.diff_args)
        # input derivatives: needed up to input_orders[j] (O uses <= n-1, G one more)
        need = max(model.input_orders, default=-1)
        self.need_u = need
        self.Du = None
        if m and not self.known_derivatives and model.uses_input_derivatives:
            q = cfg["input_order"] or n
            if q < need:
                raise ConfigError(P + "input_order", f"the map needs input derivatives up to "
                                  f"order {need}; input_order {q} is too low")
            self.Du = Differentiator(**self._differentiator_args(cfg, q, cfg["Z"], "Z", m))
        x0 = cfg["initial_estimate"] or [0.0] * n
        if len(x0) != n:
            raise ConfigError(P + "initial_estimate", f"expected {n} values, got {len(x0)}")
        self.x0_default = [float(v) for v in x0]
        self.max_condition = cfg["max_condition"]
        self.startup = model.check(self.x0_default, [0.0] * (m * (n + 1)),
                                   box=cfg["check_box"], input_box=cfg["check_input_box"],
                                   grid=cfg["check_grid"], max_condition=self.max_condition,
                                   prefix=P)
        self._x = list(self.x0_default)
        self._health = math.nan
        self._residual = math.nan
        self._etilde = math.nan
        self._active = False
        self.rejections = 0

    def _differentiator_args(self, cfg, order, L, Lname, channels) -> dict:
        args = dict(order=order, L=L, channels=channels, scheme=cfg["scheme"], rho=cfg["rho"])
        if cfg["max_step"] > 0:
            args["max_step"] = cfg["max_step"]
        if cfg["lambdas"]:
            if cfg["scheme"] == "eigenvalue_matched":
                raise ConfigError(P + "lambdas", "the eigenvalue_matched scheme places its poles "
                                  "from rho and L; lambdas apply to scheme livne_levant or euler")
            lam = cfg["lambdas"]
            if len(lam) < order + 1:
                raise ConfigError(P + "lambdas", f"need at least order + 1 = {order + 1} recursive "
                                  f"gains lambda_0..lambda_{order}, got {len(lam)}")
            try:
                args["gains"] = recursive_to_nonrecursive(lam[:order + 1])
            except ValueError as exc:
                raise ConfigError(P + "lambdas", str(exc)) from None
        try:
            Differentiator(**args)
        except ValueError as exc:
            raise ConfigError(P + (Lname if str(exc).startswith("L") else "scheme"), str(exc)) from None
        return args

    # -- helpers ----------------------------------------------------------------------------
    def _ue(self, u: np.ndarray, v: np.ndarray | None) -> list[float]:
        """Flat u_e = [u_j, u_j', ..., u_j^(n)] per input from the known channels or the
        input differentiator's estimates v (m, q+1); derivatives it does not give are 0."""
        n, m = self.n, self.model.m
        out = []
        if self.known_derivatives:
            return [float(a) for a in u]
        for j in range(m):
            if v is None:
                out.append(float(u[j]))
                out.extend([0.0] * n)
            else:
                row = v[j]
                q = len(row) - 1
                out.extend(float(row[d]) if d <= q else 0.0 for d in range(n + 1))
        return out

    # -- protocol ---------------------------------------------------------------------------
    def _restart(self, x0_hat):
        self._x = list(self.x0_default) if x0_hat is None else [float(a) for a in x0_hat]
        self._health = math.nan
        self._residual = math.nan
        self._etilde = math.nan
        self._active = False

    @property
    def max_step(self):
        # differentiator sub-steps (max_step) are bounded in number
        return self.diff_args["max_step"] * MAX_SUBSTEPS if "max_step" in self.diff_args else math.inf

    def _first(self, y, u, gap):
        n = self.n
        x = list(self._x)
        snap_u = None
        v = None
        if self.Du is not None:
            snap_u = self.Du.get_state()
            self.Du.reset(u)
            v = self.Du.estimates
        ue = self._ue(u, v)
        ev = self.model.evaluate(x, ue)
        if ev is None or not all(math.isfinite(a) for a in ev):
            if snap_u is not None:
                self.Du.set_state(snap_u)
            raise SampleRejected("model_undefined_at_estimate")
        O, J, G = ev[:n], ev[n:n + n * n], ev[n + n * n:]
        if self.ndim:
            self.Dy.reset([O[0]], [list(O[1:])])
        else:
            self.Dy.reset(y)
        eta = self.Dy.estimates[0].copy()
        self._xf = None
        if self.filter is not None:
            self._xf = self.filter.start(eta)
        self._eta_raw = eta
        self._eta = eta.copy()
        if self.filter is not None and self.filter.k:
            self._eta = (self.filter.C @ self._xf).ravel() + self.filter.D * eta
        self._x, self._J, self._G, self._O = x, J, G, O
        self._active = self.delay <= 0.0
        self._etilde = math.sqrt(sum((a - b) ** 2 for a, b in zip(eta[:n], O))) if not self.ndim else 0.0
        self._residual = abs(y[0] - O[0])
        self._health = math.nan

    def _step(self, s, h, y, u):
        n = self.n
        snap_y = self.Dy.get_state()
        snap_u = self.Du.get_state() if self.Du is not None else None
        try:
            try:
                eta_raw = self.Dy.update(h, y)[0].copy()
                v = self.Du.update(h, u) if self.Du is not None else None
            except ValueError:
                raise SampleRejected("non_finite_differentiator") from None
            ue = self._ue(u, v)
            if self.filter is not None:
                xf, eta = self.filter.step(self._xf, self._eta_raw, eta_raw, h)
            else:
                xf, eta = None, eta_raw
            x = self._x
            active = s >= self.delay - 1e-12
            if not active:
                ev = self.model.evaluate(x, ue)
                if ev is None:
                    raise SampleRejected("model_undefined_at_estimate")
                x_new = x
                O = ev[:n]
                et = 0.0 if self.ndim else math.sqrt(sum((eta[i] - O[i]) ** 2 for i in range(n)))
            else:
                # 1. feed-forward: trapezoid on eta^(1,n) (filtered) or the increment of
                #    xi (n_dimensional), explicit on G, with J from the last evaluation
                Gp = self._G
                if self.ndim:
                    ff = [eta[i] - self._eta[i] - h * Gp[i] for i in range(n)]
                else:
                    ff = [0.5 * h * (self._eta[i + 1] + eta[i + 1]) - h * Gp[i] for i in range(n)]
                dx = solve(self._J, ff, n)
                if dx is None:
                    raise SampleRejected("singular_jacobian")
                xp = [a + b for a, b in zip(x, dx)]
                # 2. stiff part at the new sample: backward Euler on eta~, one Newton step
                ev = self.model.evaluate(xp, ue)
                if ev is None:
                    raise SampleRejected("model_undefined_at_estimate")
                O = ev[:n]
                e_pred = [eta[i] - O[i] for i in range(n)]
                et = math.sqrt(sum(a * a for a in e_pred))
                if self.ndim:
                    corr = e_pred
                else:
                    e_new = implicit_flow(e_pred, h * self.mu, self.alpha)
                    corr = [a - b for a, b in zip(e_pred, e_new)]
                dx2 = solve(ev[n:n + n * n], corr, n)
                if dx2 is None:
                    raise SampleRejected("singular_jacobian")
                x_new = [a + b for a, b in zip(xp, dx2)]
            J, G = ev[n:n + n * n], ev[n + n * n:]
            if not (math.isfinite(sum(x_new)) and math.isfinite(sum(ev))
                    and np.all(np.isfinite(eta)) and (xf is None or np.all(np.isfinite(xf)))):
                raise SampleRejected("non_finite_estimate")
        except SampleRejected:
            self.Dy.set_state(snap_y)
            if snap_u is not None:
                self.Du.set_state(snap_u)
            self.rejections += 1
            raise
        # commit
        self._x, self._J, self._G, self._O = x_new, J, G, O
        self._eta_raw, self._eta, self._xf = eta_raw, eta, xf
        self._active, self._etilde = active, et
        self._residual = abs(y[0] - O[0])
        self._health = math.nan          # cond(J) computed on demand

    # -- outputs ----------------------------------------------------------------------------
    @property
    def estimate(self):
        return np.array(self._x, dtype=float)

    @property
    def health(self):
        if not self.started:
            return math.nan
        if math.isnan(self._health):
            J = np.asarray(self._J, dtype=float).reshape(self.n, self.n)
            self._health = float(np.linalg.cond(J))
        return self._health

    @property
    def eta(self) -> np.ndarray:
        """The derivative estimates used by the inversion (filtered when a filter is set)."""
        return np.array(self._eta, dtype=float)

    @property
    def inversion_active(self) -> bool:
        return self._active

    def diagnostics(self):
        s = self.startup
        out = {
            "variant": "n_dimensional (21)" if self.ndim else
                       ("filtered (11) + Q(s) (Remark 6)" if self.filter is not None else "(11)"),
            "inversion active": "yes" if self._active else f"no (delay {self.delay:g} s)",
            "cond(J)": f"{self.health:.4g}",
            "|eta_tilde|": f"{self._etilde:.3g}",
            "differentiator residual |y - eta_0|": f"{float(self.Dy.residual[0]):.3g}"
            if self.started else "n/a",
            "input derivatives": "known (input channels)" if self.known_derivatives else
                                 ("estimated (Remark 5)" if self.Du is not None else "not needed"),
            "start-up cond(J) at x_hat(0)": f"{s['cond_at_x0']:.4g}",
            "samples rejected by the observer": str(self.rejections),
        }
        if "box_max_cond" in s:
            out["start-up max cond(J) over the box"] = f"{s['box_max_cond']:.4g}"
            out["start-up sigma_min^2 .. sigma_max^2 over the box"] = (
                f"{s['box_min_sigma2']:.4g} .. {s['box_max_sigma2']:.4g}")
        return out
