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
for polynomial y, predictor-corrector model term): global_norm/companion.py.

This module is the adapter (parameters, gains, the kernel's arrays); the per-sample step is
kernel.py.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.expressions import NamedFunction
from ...core.model_code import ModelFunction
from ...core.step_cache import cache_floats, cache_init
from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param
from ..chain_map import PARAM as CHAIN_MAP, chain_map, write_map
from . import kernel

P = "high_gain."


class HighGainObserver(KernelObserver):
    KERNEL = kernel
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
        CHAIN_MAP,
    )

    def __init__(self, cfg: dict):
        m = cfg["n_states"]
        T = chain_map(cfg, m, P)
        self.n_states, self.n_outputs, self.n_inputs = m, 1, cfg["n_inputs"]
        if cfg["f"] is None:
            raise ConfigError(P + "f", "required: f_n(y, x1, .., xn)")
        self.f = NamedFunction([cfg["f"]], ["y"] + [f"x{i}" for i in range(1, m)]
                               + [f"u{j}" for j in range(self.n_inputs)], P + "f")
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
        self.M = cfg["saturation"]
        self.on_estimate = cfg["model_input"] == "estimate"
        self.quadratic = cfg["output_hold"] == "quadratic"
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(m)]
        if len(self.state_names) != m:
            raise ConfigError(P + "state_names", f"expected {m} names, got {len(self.state_names)}")
        self._build()
        if T is not None:
            self.map_states(T)

    def _build(self) -> None:
        """The kernel's arrays (kernel.py has the layout)."""
        m, nin = self.n_states, self.n_inputs
        slots = kernel.CACHE_SLOTS
        cache = cache_floats(slots, m * m)
        wk = np.zeros(cache + kernel.scratch_size(m))
        cache_init(wk, 0, slots)
        ic = K.layout_ic(m, kernel.X_HAT, extra_ints=(
            m, nin, int(self.on_estimate), int(self.quadratic), 0, slots, cache, 0))
        eye = np.eye(m).ravel()
        c = np.concatenate(([math.inf, self.M], self.gains, [-g for g in self.gains], eye, eye))
        syms = self.f.syms
        model = ModelFunction(self.f.exprs, [syms[1:m], syms[:1], syms[m:]])
        self._build_kernel(c, ic, wk, kernel.state_size(m, nin), models=(model,))
        self._st[K.HEALTH] = float(self.L)

    def map_states(self, T: np.ndarray) -> None:
        """Run on z = T x and take and publish plant coordinates (chain_map.py): an initial
        estimate x0 becomes T x0, the estimate is T^-1 z_hat."""
        m = self.n_states
        write_map(self._c, kernel.t_map(m), T)
        self._ic[kernel.MAPPED] = 1
        self._ic[K.EST] = kernel.published(m, self.n_inputs)
        self._restart(None)

    def diagnostics(self):
        return {
            "gains": ", ".join(f"{g:.4g}" for g in self.gains),
            "saturation": f"+-{self.M:g}" if self.M > 0 else "none",
            "model term at": "the estimate" if self.on_estimate else "y and the estimates",
            "saturation active": "yes" if self._st[kernel.SAT_ACTIVE] > 0.0 else "no",
            "saturated steps": str(int(self._st[kernel.SAT_COUNT])),
            "guarantee": "semi-global: only while |x_i| <= M (none for escaping trajectories)",
        }
