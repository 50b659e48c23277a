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

This module is the adapter (parameters, design, the kernel's arrays, what the state says);
the per-sample work is kernel.py, the paper's design quantities design.py.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.discretize import MAX_SUBSTEPS, STEP_QUANTUM
from ...core.expressions import VectorFunction
from ...core.model_code import ModelFunction
from ...core.step_cache import cache_floats, cache_init
from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param, matrix
from . import kernel, layout, windows
from .design import (GUARD_DEFAULT, GUARD_FROM_ORDER, MAX_M, MAX_ORDER, MAX_T,
                     bandwidth_factor, c_matrix, gain_coefficients, hurwitz_roots,
                     inverse_unit_lower, is_hurwitz, mu_at_gain, p_bar)

P = "prescribed_time."
#: entries of each step-size cache (model step, E_bar, after the window)
CACHE_SLOTS = 256


class PrescribedTimeObserver(KernelObserver):
    TYPE = "prescribed_time"
    KERNEL = kernel
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
        self.Cinv = inverse_unit_lower(Cint)
        self.pbar = p_bar(n, m, self.T)
        self.Hg = gain_coefficients(n, m, self.T, l)           # g_i(mu) = Hg[i] . mu^k
        self._exps = np.arange(n + 1, dtype=float)
        self._cell = np.zeros(1)
        self._mu_pow = np.empty(n + 1)
        self._g = np.empty(n)

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
            s_cap = self.T * (1.0 - 1.0 / mu_at_gain(self.Hg, g_max))
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
            if self.g_end is not None and not is_hurwitz(self.g_end):
                eig = hurwitz_roots(self.g_end)
                raise ConfigError(P + "mode", "'constant': the frozen gains "
                                  f"{np.array2string(self.g_end, precision=4)} do not give a "
                                  "Hurwitz A - g e_1' (eigenvalues "
                                  + ", ".join(f"{z:.4g}" for z in eig)
                                  + "); choose another g_max / t_stop")

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
        self._build(Ap, np.hstack(cols))

    def _build(self, Ap: np.ndarray, B: np.ndarray) -> None:
        """The kernel's arrays (kernel.py documents them, layout.py places them)."""
        n, w = self.n, B.shape[1]
        zeros = np.zeros(n)
        arrays = (self.Hg, self.C, self.Cinv, self.l, zeros if self.g_end is None else self.g_end,
                  Ap, B, np.eye(n) if self.Smap is None else self.Smap, self._exps)
        offsets, o = [], layout.C_ARRAYS
        for arr in arrays:
            offsets.append(o)
            o += arr.size
        c = np.concatenate(([self.s_end * MAX_SUBSTEPS if self.mode == "restart" else math.inf,
                             self.T, self.s_end, self.beta_guard, float(n + self.m)],
                            *(np.ravel(arr) for arr in arrays)))
        slots = CACHE_SLOTS
        caches = [layout.WK_HEADER]
        for size in (n * (n + 2 * w), n * n, n * n):
            caches.append(caches[-1] + cache_floats(slots, size))
        wk = np.zeros(caches[-1] + layout.scratch_size(n, w))
        for base in caches[:3]:
            cache_init(wk, base, slots)
        wk[layout.WK_AFTER_ID] = -1.0
        ic = K.layout_ic(n, layout.X_PUB, extra_ints=(
            n, self.n_inputs, int(self.F is not None), layout.MODES.index(self.mode),
            int(self.g_end is not None), int(self.Smap is not None),
            int(self.reset_keeps_estimate), int(self.foh_input), w, *caches, slots, *offsets))
        models = () if self.F is None else (
            ModelFunction(self.F.exprs, [[], self.F.y_syms, self.F.u_syms]),)
        self._build_kernel(c, ic, wk, layout.state_size(n), models=models)
        st = self._st
        st[K.GUARANTEED] = self.T
        st[K.HEALTH] = 0.0
        st[layout.HAS_FROZEN] = float(self.mode == "constant" and self.g_end is not None)
        st[layout.FROZEN_ID] = -1.0
        self._state_vec(3)[:] = zeros if self.g_end is None else self.g_end

    # -- the paper's functions ----------------------------------------------------
    def gains_at(self, mu: float) -> np.ndarray:
        """g_1..g_n at mu_1 = mu (Lemma 4 polynomials), into a preallocated buffer."""
        windows.gains(self.Hg, self._exps, float(mu), self._cell, self._mu_pow, self._g)
        return self._g

    def transition_window(self, v: np.ndarray, sa: float, sb: float) -> np.ndarray:
        """Phi(t0 + sb, t0 + sa) v for the error system (8)-(9) inside one window, 0 <= sa < sb <= T.

        Exact (Lemma 1): the scaled product of the module docstring; sb = T gives 0.
        """
        out = np.empty(self.n)
        windows.transition(self._c, self._ic, self._wk, np.ascontiguousarray(v, dtype=float),
                          float(sa), float(sb), out)
        return out

    # -- what the state says ----------------------------------------------------------
    def _state_vec(self, k: int) -> np.ndarray:
        """State vector k (kernel.py: 0 x published, 1 x, 2 F, 3 frozen gains), a view."""
        o = layout.X_PUB + k * self.n
        return self._st[o:o + self.n]

    def _flag(self, i: int) -> bool:
        return bool(self._st[i] > 0.0)

    @property
    def _t(self) -> float | None:
        """Model time of the last sample since the first one ever (None: none since the
        last restart)."""
        return float(self._st[layout.T_MODEL]) if self._flag(layout.HAS_T) else None

    @property
    def _tw(self) -> float:
        return float(self._st[layout.TW])

    @property
    def _frozen(self) -> np.ndarray | None:
        return self._state_vec(3).copy() if self._flag(layout.HAS_FROZEN) else None

    @property
    def gains(self) -> np.ndarray:
        """g_1..g_n at the last sample (0 after the window in mode stop)."""
        if self._t is None:
            return np.zeros(self.n)
        out = np.empty(self.n)
        kernel.gains_now(self._st, self._c, self._ic, self._wk, self._t, out)
        return out

    @property
    def injections(self) -> np.ndarray:
        """gamma_i = g_i (y - x_hat_1) at the last sample (Theorem 1: bounded)."""
        return self.gains * float(self._st[layout.POST])

    @property
    def window_start(self) -> float:
        """Start of the current window (the stamps' time base)."""
        return float(self._clk[K.CLK_T0] + self._tw - self._st[layout.KSTART] * STEP_QUANTUM)

    @property
    def after_window(self) -> bool:
        return self._flag(layout.AFTER)

    @property
    def restarts(self) -> int:
        """Window restarts since the last reset (mode restart)."""
        return int(self._st[layout.RESTARTS])

    @property
    def restarts_total(self) -> int:
        return int(self._st[layout.RESTARTS_TOTAL])

    @property
    def last_end(self) -> tuple[float, str] | None:
        """(model time, reason) of the last window end, or None."""
        if not self._flag(layout.HAS_END):
            return None
        why = "sampling limit" if self._st[layout.END_REASON] == layout.END_SAMPLING else self.end_reason
        return float(self._st[layout.END_T]), why

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
        if self.after_window:
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
        out["largest gain since reset"] = f"{float(self._st[layout.G_PEAK]):.4g}"
        out["gamma_i = g_i (y - x_hat_1)"] = ", ".join(f"{v:.4g}" for v in self.injections)
        out["largest |gamma_i| (health)"] = f"{self.health:.4g}"
        return out
