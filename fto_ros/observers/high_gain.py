"""Constant-gain high-gain observer (the comparison for ``global_norm``).

Plant in observability form x0' = x1, ..., xn' = f_n(x0, .., xn), y = x0.  Observer::

    xh_i' = xh_{i+1} + alpha_i L^(i+1) (y - xh_0)          i = 0 .. n-1
    xh_n' = f_n(y, sat_M(xh_1), .., sat_M(xh_n)) + alpha_n L^(n+1) (y - xh_0)

(``model_input: estimate``: f_n(sat_M(xh_0), ..., sat_M(xh_n)), the textbook form in which
the model is evaluated at the estimate only; then an f_n whose Lipschitz constant grows
with |x| (y**3) outruns any constant L on a growing trajectory, even without saturation.)

with s^(n+1) + alpha_0 s^n + ... + alpha_n Hurwitz (default: all roots at -1, so the error
poles are all at -L).  Following Khalil's practice (Khalil & Praly 2014), the unmeasured
estimates entering the model term are saturated at +-M (``saturation``: M; 0 means no
saturation): this is what makes the semi-global theory work when the state stays in a
KNOWN compact set |x_i| <= M, and what makes it fail when the trajectory leaves every
compact set (finite escape).  Same exact integrator as ``global_norm`` (linear part exact
for polynomial y, predictor-corrector model term).
"""
from __future__ import annotations

import math

import numpy as np

from ..core.discretize import StepCache
from ..core.expressions import NamedFunction
from .base import ConfigError, Observer, Param, SampleRejected
from .global_norm import companion_expm, companion_step, output_polynomial

P = "high_gain."


class HighGainObserver(Observer):
    TYPE = "high_gain"
    DESCRIPTION = "constant-gain high-gain observer with saturated model term (semi-global)"
    HEALTH_NAME = "high gain L"
    PARAMS = (
        Param("n_states", "int", 2, "number of states x0 .. xn", min=2, max=6),
        Param("f", "string", None, "f_n(y, x1, .., xn, u0, ..), y standing for x0, u0.. the known "
              "inputs, e.g. '-x1 + y**3 + u0'"),
        Param("n_inputs", "int", 0, "number of known inputs u0.. in f (held between samples)",
              min=0, max=32),
        Param("L", "double", 10.0, "the high gain L (> 0): error poles at -L times the roots of "
              "the alpha polynomial", min=1e-9),
        Param("alpha", "double_array", [], "alpha_0 .. alpha_n, s^(n+1) + alpha_0 s^n + .. + "
              "alpha_n Hurwitz (empty: binomial, all roots at -1)"),
        Param("saturation", "double", 0.0, "M: the estimates x1..xn in the model term are "
              "clipped to [-M, M] (0: no saturation)", min=0.0),
        Param("model_input", "string", "measured", "what the model term f_n takes for x0: "
              "'measured' (y, as global_norm does) or 'estimate' (xh_0, saturated like the "
              "others: Khalil's textbook form)", choices=("measured", "estimate")),
        Param("output_hold", "string", "quadratic", "y between samples: 'foh' or 'quadratic'",
              choices=("foh", "quadratic")),
        Param("state_names", "string_array", [], "names of the states (empty: x0, x1, ...)"),
    )

    def __init__(self, cfg: dict):
        m = cfg["n_states"]
        self.n_states, self.n_outputs, self.n_inputs = m, 1, cfg["n_inputs"]
        if cfg["f"] is None:
            raise ConfigError(P + "f", "required: f_n(y, x1, .., xn)")
        self.f = NamedFunction([cfg["f"]], ["y"] + [f"x{i}" for i in range(1, m)]
                               + [f"u{j}" for j in range(self.n_inputs)], P + "f")
        self._u = (0.0,) * self.n_inputs        # the input held over the current step
        alpha = cfg["alpha"] or [float(math.comb(m, i + 1)) for i in range(m)]
        if len(alpha) != m:
            raise ConfigError(P + "alpha", f"expected {m} values, got {len(alpha)}")
        roots = np.roots([1.0] + list(alpha))
        if np.max(roots.real) >= 0:
            raise ConfigError(P + "alpha", f"s^{m} + alpha_0 s^{m-1} + ... is not Hurwitz "
                              f"(roots {np.round(roots, 4).tolist()})")
        L = cfg["L"]
        self.L = L
        try:
            self.gains = [alpha[i] * L ** (i + 1) for i in range(m)]
        except OverflowError:
            self.gains = [math.inf]
        if not all(math.isfinite(g) for g in self.gains):
            raise ConfigError(P + "L", f"the gains alpha_i L^(i+1) overflow a double at L = {L:g} "
                              f"(n = {m}): use a smaller L")
        self._c = [-g for g in self.gains]
        self.M = cfg["saturation"]
        self.on_estimate = cfg["model_input"] == "estimate"
        self.quadratic = cfg["output_hold"] == "quadratic"
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(m)]
        if len(self.state_names) != m:
            raise ConfigError(P + "state_names", f"expected {m} names, got {len(self.state_names)}")
        self._E_cache = StepCache(lambda h: companion_expm(self._c, h), 64)
        self._x = [0.0] * m
        self._residual = float("nan")
        self._sat = False
        self._sat_count = 0

    def _restart(self, x0_hat):
        m = self.n_states
        self._x = [0.0] * m if x0_hat is None else [float(v) for v in x0_hat]
        self._y = self._yprev = self._hprev = None
        self._sat_count = 0

    def _model(self, y, x):
        """f_n at (y or xh_0, xh_1..xh_n), the estimates saturated at M, and whether clipped."""
        xbar = list(x) if self.on_estimate else list(x[1:])
        M = self.M
        sat = False
        if M > 0:
            clipped = [min(M, max(-M, v)) for v in xbar]
            sat = clipped != list(xbar)
            xbar = clipped
        fv = self.f(*xbar, *self._u)[0] if self.on_estimate else self.f(y, *xbar, *self._u)[0]
        if fv != fv or math.isinf(fv):
            raise SampleRejected("non_finite_model_term")
        return fv, sat

    def _first(self, y, u, gap):
        self._y = float(y[0])
        self._residual = abs(self._y - self._x[0])
        self._u = tuple(u)

    def _step(self, s, h, y, u):
        yk = float(y[0])
        E = self._E_cache(h)
        c, G, m, x0 = self._c, self.gains, self.n_states, self._x
        ya, yb, yc = output_polynomial(self._yprev, self._hprev, self._y, yk, h, self.quadratic)
        v0, _ = self._model(self._y, x0)
        r0 = [G[i] * ya for i in range(m)]
        r1 = [G[i] * yb for i in range(m)]
        r2 = [G[i] * yc for i in range(m)]
        r0[-1] += v0
        try:
            xp = companion_step(c, E, x0, h, r0, r1, r2)
            v1, _ = self._model(yk, xp)
            r1[-1] += (v1 - v0) / h
            x = companion_step(c, E, x0, h, r0, r1, r2)
        except (OverflowError, ZeroDivisionError, ValueError):
            raise SampleRejected("non_finite_estimate") from None
        if not all(math.isfinite(v) for v in x):
            raise SampleRejected("non_finite_estimate")
        _, sat = self._model(yk, x)
        self._x, self._sat = x, sat
        self._sat_count += sat
        self._yprev, self._hprev = self._y, h
        self._y = yk
        self._residual = abs(yk - x[0])
        self._u = tuple(u)

    @property
    def estimate(self):
        return np.array(self._x, dtype=float)

    @property
    def health(self):
        return float(self.L)

    def diagnostics(self):
        return {
            "gains": ", ".join(f"{g:.4g}" for g in self.gains),
            "saturation": f"+-{self.M:g}" if self.M > 0 else "none",
            "model term at": "the estimate" if self.on_estimate else "y and the estimates",
            "saturation active": "yes" if self._sat else "no",
            "saturated steps": str(self._sat_count),
            "guarantee": "semi-global: only while |x_i| <= M (none for escaping trajectories)",
        }
