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
(Cardano + Newton polish for 3x3, numpy's roots beyond) otherwise, a Taylor series of the
balanced matrix when |lambda| h < 1/2, scipy's expm algorithm (compiled) when eigenvalues
cluster: companion.py.  This is stable and exact in the linear part for ANY gain size (the
gains grow with w without bound); the model term v is a predictor-corrector (Heun) pair.

This module is the adapter (parameters, the conditions, the kernel's arrays, what the state
says); the per-sample step is kernel.py.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import sympy

from ...core.errors import ConfigNote
from ...core.expressions import NamedFunction, compile_exprs, parse
from ...core.model_code import ModelFunction
from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param
from ..chain_map import PARAM as CHAIN_MAP, chain_map, write_map
from . import kernel
from .design import default_c, gain_exprs, gains_numeric

P = "global_norm."


class GlobalNormObserver(KernelObserver):
    KERNEL = kernel
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
        CHAIN_MAP,
    )

    def __init__(self, cfg: dict):
        m = cfg["n_states"]
        n = m - 1
        T = chain_map(cfg, m, P)
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
            c = cfg["c"] or ([1.0] if self.reduced else []) + default_c(m - 1 if self.reduced else m)
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
        self._build(outs, wsym, xnames)
        if T is not None:
            self.map_states(T)

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

    def _build(self, outs, wsym, xnames) -> None:
        """The kernel's arrays (kernel.py has the layout)."""
        m, dim, nin = self.n_states, self._dim, self.n_inputs
        ic = K.layout_ic(m, kernel.X_HAT, extra_ints=(
            m, dim, nin, int(self.reduced), int(self.quadratic), 0, 0))
        ysym = self.f.syms[0]
        models = (ModelFunction(outs, [[wsym]]),
                  ModelFunction(self.f.exprs, [self.f.syms[1:m], [ysym], self.f.syms[m:]]),
                  ModelFunction(self.gamma_1.exprs, [[], self.gamma_1.syms]))
        eye = np.eye(m).ravel()
        self._build_kernel(np.concatenate(([math.inf, self.w0], eye, eye)), ic,
                           np.zeros(kernel.scratch_size(m, dim)), kernel.state_size(m, dim, nin),
                           models=models)
        self._restart(None)

    def map_states(self, T: np.ndarray) -> None:
        """Run on z = T x and take and publish plant coordinates (chain_map.py): an initial
        estimate x0 becomes T x0, the estimate is T^-1 z_hat."""
        m = self.n_states
        write_map(self._c, kernel.T_MAP, T)
        self._ic[kernel.MAPPED] = 1
        self._ic[K.EST] = kernel.published(m, self._dim, self.n_inputs)
        self._restart(None)

    # -- what the state says ------------------------------------------------------------
    @property
    def w(self) -> float:
        """The norm estimator's state."""
        return float(self._st[kernel.W])

    @property
    def gamma_hat(self) -> float:
        return float(self._st[kernel.GH])

    @property
    def injection_gains(self) -> list[float]:
        """The gains multiplying (y - xh_0) in eq. (85), i.e. -k_i(w) (full form), or k_i(w)."""
        o = kernel.X_HAT + self.n_states
        k = self._st[o:o + self._dim].tolist()
        return [-v for v in k] if not self.reduced else k

    def diagnostics(self):
        out = {
            "form": "full-order (eq. 85)" if not self.reduced else "reduced-order (eq. 83-84)",
            "w (norm estimator)": f"{self.w:.6g}",
            "gamma_hat(w)": f"{self.gamma_hat:.6g}",
            "gains": ", ".join(f"{g:.4g}" for g in self.injection_gains),
            "saturation active": "yes" if self._st[kernel.SAT_ACTIVE] > 0.0 else "no",
            "saturated steps": f"{int(self._st[kernel.SAT_COUNT])} of {int(self._st[kernel.STEPS])}",
            "guarantee": "asymptotic, global (Theorem 3): error -> 0 as t -> escape time or infinity",
        }
        if self.warnings:
            out["conditions"] = "WARN: " + "; ".join(self.warnings)
        else:
            out["conditions"] = "footnote-6 checks passed on the grid"
        return out
