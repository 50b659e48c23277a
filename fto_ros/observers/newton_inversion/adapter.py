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
to x_hat by one Newton step with J at the predicted point.  The per-sample step is the
compiled kernel (observers/newton_inversion/kernel.py), transactional: a rejected sample
leaves every state, the differentiators' included, untouched.

No guaranteed time is published (the base class's inf): Theorem 2 / Corollary 1 make the
convergence time finite, but T* depends on constants (M, N, S) that are not computable
from the model in general.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.differentiator import SCHEMES, Differentiator, recursive_to_nonrecursive
from ...core.discretize import MAX_SUBSTEPS
from ...core.layout import Layout
from ...core.step_cache import cache_floats, cache_init
from ...core.symbolic_model import SymbolicModel
from .. import kernel as KP
from ..base import ConfigError, KernelObserver, Param
from . import kernel as K
from . import numerics

P = "newton_inversion."


# ----------------------------------------------------------------------------- numerics
def implicit_flow(e, c: float, alpha: float) -> list[float]:
    """The backward-Euler step of e' = -mu |e|_2^alpha sign(e), c = h mu (numerics.py), on a
    sequence: the list e+."""
    e = np.ascontiguousarray(e, dtype=float)
    out = np.empty_like(e)
    numerics.implicit_flow(e, float(c), float(alpha), out, np.empty_like(e))
    return out.tolist()


class LinearFilter:
    """Q(s) = num(s)/den(s) (proper) on `channels` signals: the controllable canonical form
    (A, B, C, D) the kernel steps exactly with its input first-order held."""

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
            self.dc_state = -np.linalg.solve(A, B)          # state for a unit constant input
        self.dc_gain = float(np.polyval(num, 0.0) / np.polyval(den, 0.0)) if den[-1] != 0 else math.nan


# ----------------------------------------------------------------------------- observer
class NewtonInversionObserver(KernelObserver):
    TYPE = "newton_inversion"
    KERNEL = K
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
        self._dy = Differentiator(**self.diff_args)
        # input derivatives: needed up to input_orders[j] (O uses <= n-1, G one more)
        need = max(model.input_orders, default=-1)
        self.need_u = need
        self._du = None
        if m and not self.known_derivatives and model.uses_input_derivatives:
            q = cfg["input_order"] or n
            if q < need:
                raise ConfigError(P + "input_order", f"the map needs input derivatives up to "
                                  f"order {need}; input_order {q} is too low")
            self._du = Differentiator(**self._differentiator_args(cfg, q, cfg["Z"], "Z", m))
        x0 = cfg["initial_estimate"] or [0.0] * n
        if len(x0) != n:
            raise ConfigError(P + "initial_estimate", f"expected {n} values, got {len(x0)}")
        self.x0_default = [float(v) for v in x0]
        self.max_condition = cfg["max_condition"]
        self.startup = model.check(self.x0_default, [0.0] * (m * (n + 1)),
                                   box=cfg["check_box"], input_box=cfg["check_input_box"],
                                   grid=cfg["check_grid"], max_condition=self.max_condition,
                                   prefix=P)
        self._build(order + 1)

    def _build(self, ne: int) -> None:
        """The kernel's arrays (observers/newton_inversion/kernel.py has the layout)."""
        n, m = self.n, self.model.m
        dy, du, flt = self._dy, self._du, self.filter
        k = flt.k if flt is not None else 0
        c, ic = Layout(1), {}                        # c[MAX_STEP] first
        ic[K.CX0] = c.put(self.x0_default)
        ic[K.CPAR] = c.put([self.mu, self.alpha, self.delay])
        ic[K.CDY] = c.put(dy.consts)
        ic[K.CDU] = c.put(du.consts) if du is not None else 0
        if flt is not None and k:
            ic[K.CAF], ic[K.CBF], ic[K.CCF] = c.put(flt.A), c.put(flt.B), c.put(flt.C)
            ic[K.CDC] = c.put(flt.dc_state)
        else:
            ic[K.CAF] = -1 if flt is None else c.size
            ic[K.CBF] = ic[K.CCF] = ic[K.CDC] = c.size
        ic[K.CDF] = c.put([flt.D if flt is not None else 0.0])
        s = Layout(KP.HEADER)
        s.take(n)                                      # x
        for key, size in ((K.SJ, n * n), (K.SG, n), (K.SO, n), (K.SRAW, ne), (K.SETA, ne),
                          (K.SXF, k * ne), (K.SACT, 1), (K.SET, 1), (K.SDY, dy.state_size),
                          (K.SDU, du.state_size if du is not None else 0)):
            ic[key] = s.take(size)
        slots = 256
        w = Layout(0)
        ic[K.WFC], ic[K.FSLOTS] = w.take(cache_floats(slots, k * (k + 2))), slots
        for key, size in ((K.WREJ, 1), (K.WEV, 2 * n + n * n), (K.WUE, m * (n + 1)),
                          (K.WT, 6 * n), (K.WW, n * n), (K.WFT, k * k + k * ne),
                          (K.WR, max(dy.scratch_size, du.scratch_size if du else 0))):
            ic[key] = w.take(size)
        wk = np.zeros(w.size)
        cache_init(wk, ic[K.WFC], slots)
        ints = [n, m, m * (n + 1), int(self.known_derivatives), int(self.ndim), ne,
                int(du is not None), k] + [ic[key] for key in range(K.CX0, K.WR + 1)]
        icv = KP.layout_ic(n, KP.HEADER, extra_ints=ints)
        # differentiator sub-steps (max_step) are bounded in number
        c.data[KP.MAX_STEP] = (self.diff_args["max_step"] * MAX_SUBSTEPS
                               if "max_step" in self.diff_args else math.inf)
        self._build_kernel(c.array(), icv, wk, s.size, models=(self.model.function,))
        self._restart(None)                            # x_hat = x_hat(0) until a sample

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

    # -- views of the kernel's state -----------------------------------------------------
    @property
    def Dy(self) -> Differentiator:
        """The output differentiator, a view of its state in the observer's."""
        return self._dy.on(self._st, int(self._ic[K.SDY]))

    @property
    def Du(self) -> Differentiator | None:
        """The input differentiator (Remark 5; None: not needed), a view of its state."""
        return None if self._du is None else self._du.on(self._st, int(self._ic[K.SDU]))

    @property
    def eta(self) -> np.ndarray:
        """The derivative estimates used by the inversion (filtered when a filter is set)."""
        o = int(self._ic[K.SETA])
        return self._st[o:o + int(self._ic[K.NE])].copy()

    @property
    def inversion_active(self) -> bool:
        return bool(self._st[int(self._ic[K.SACT])])

    @property
    def rejections(self) -> int:
        """Samples the observer itself rejected (model undefined, singular J, ...)."""
        return int(self._wk[int(self._ic[K.WREJ])])

    def diagnostics(self):
        s = self.startup
        out = {
            "variant": "n_dimensional (21)" if self.ndim else
                       ("filtered (11) + Q(s) (Remark 6)" if self.filter is not None else "(11)"),
            "inversion active": "yes" if self.inversion_active else f"no (delay {self.delay:g} s)",
            "cond(J)": f"{self.health:.4g}",
            "|eta_tilde|": f"{self._st[int(self._ic[K.SET])]:.3g}",
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
