"""Fixed-time reduced-order observer with a single delay (Mazenc & Malisoff 2022).

Plant, in the paper's coordinates (eq. 2):

    xi1' = A1 xi1 + F1(Y, u)                 xi1: the n1 unmeasured states
    xi2' = A2 xi1 - k xi2 + F2(Y, u)         xi2: the q measured states,  Y = xi2

with (A1, A2) observable and A1 + k I invertible.  The parameter ``single_delay.F2`` is the
plant's own term G in xi2' = A2 xi1 + G(Y, u); the observer forms the paper's
F2 = G + k Y from k, so changing k at run time keeps the two consistent.  The dynamic
extension (7)

    xh1' = A1 xh1 + F1(Y, u)
    xh2' = A2 xh1 - k xh2 + F2(Y, u)
    psi1' = -k psi1 + H (Y - xh2)
    psi2' = -(A1^T + 2 k I) psi2 + H (Y - xh2)

and the single delay tau give, for every t >= t0 + tau (eq. 13),

    xi1(t) = xh1 + R (Y - xh2) + S^-1 [e^{-k tau} psi1(t - tau) - psi1]
                               + S^-1 [psi2 - e^{-(A1^T + 2kI) tau} psi2(t - tau)]

exactly (Theorem 1), whatever the initial conditions.  S is the Gramian (5) of
lambda(r) = A2 (A1 + kI)^-1 [I - e^{(A1 + kI) r}], R = S^-1 N (6), H (6).

Two forms share this adapter's parameters, checks and design (design.py), each with a
kernel of its own; the observer runs the one ``measurement`` names (``self.form``: what
the forms differ in, below).

- ``Continuous`` (``measurement: continuous``, Theorem 1; continuous.py): the
  linear extension is integrated exactly between samples (Y and F(Y, u) first-order hold,
  u held or linear), the delayed combination of psi1, psi2 is kept in a Hermite delay ring,
  so irregular sampling is fine.  The only approximation is the hold of Y between samples:
  O(h^2).
- ``Sampled`` (``measurement: sampled``, Theorem 2, eq. 39; sampled.py): Y only
  at sparse instants t_j; between them the predictor omega' = A2 xi_e - k omega +
  F2(omega, u) stands in for Y and is reset to Y(t_j) at each sample; integrated in
  sub-steps of at most ``substep`` (exact linear part, Heun for the nonlinear F), and
  advanced on every input message (the kernel's ADVANCE) so fast inputs are not lost.

Before t0 + tau the estimate is the open-loop copy xh1 (no guarantee yet).

The delay ring has a fixed capacity (kernel.py): it keeps a window of up to
WINDOW_ENTRIES = 4096 entries whole (1 kHz for tau up to 4 s); a faster stream is thinned to
entries tau / 4096 apart (24 us for tau = 0.1 s), the read at t - tau then interpolates
between them (fourth order), and memory per observer stays fixed whatever the rate.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from ...core.discretize import MAX_SUBSTEPS, STEP_QUANTUM
from ...core.errors import ConfigNote
from ...core.expressions import VectorFunction
from ...core.linear import observability_rank
from ...core.model_code import ModelFunction
from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param, matrix
from . import continuous as continuous_form, sampled as sampled_form
from . import kernel as SD
from .design import (MAX_QUADRATURE_ERROR, MAX_RATE_TAU, MAX_TAU, design, extension,
                     noise_bound_constant, predictor, quadrature_error, readout, theorem2_mu)

P = "single_delay."


class SingleDelayObserver(KernelObserver):
    """The single-delay observer, in the form ``measurement`` names (``form``: Continuous
    or Sampled)."""

    TYPE = "single_delay"
    DESCRIPTION = "Mazenc & Malisoff 2022: exact after the delay tau (fixed time), reduced order"
    HEALTH_NAME = "|S^-1 d(t - tau)|, the delayed correction"
    PARAMS = (
        Param("n_unmeasured", "int", None, "n1 = n - q, size of the unmeasured part xi1", min=1, max=32),
        Param("n_outputs", "int", 1, "q, number of measured outputs (= size of xi2)", min=1, max=32),
        Param("n_inputs", "int", 0, "m, number of known inputs", min=0, max=32),
        Param("A1", "double_array", None, "n1 x n1 matrix of eq. (2), row-major", read_only=False),
        Param("A2", "double_array", None, "q x n1 matrix of eq. (2), row-major; (A1, A2) observable", read_only=False),
        Param("k", "double", None, "k > 0 of eq. (2); A1 + k I must be invertible", min=0.0, read_only=False),
        Param("tau", "double", None, "the delay = the guaranteed convergence time (s), > 0", min=0.0, read_only=False),
        Param("F1", "string_array", [], "n1 known terms in y0.. and u0.. (eq. 2; empty: zeros)", read_only=False),
        Param("F2", "string_array", [], "q known terms G(y, u) of the measured states' own "
              "dynamics, xi2' = A2 xi1 + G (empty: zeros); the observer adds the k y of eq. (2) "
              "itself, so k and F2 never drift apart", read_only=False),
        Param("lipschitz_K1", "double", 0.0, "Lipschitz constant of F1 in y (eq. 3), for the bounds", min=0.0, read_only=False),
        Param("lipschitz_K2", "double", 0.0, "Lipschitz constant of G (single_delay.F2) in y; the "
              "bounds of eq. (3) use it plus k", min=0.0, read_only=False),
        Param("measurement", "string", "continuous", "'continuous' (Theorem 1) or 'sampled' (Theorem 2: "
              "y at sparse instants, predictor between them)", choices=("continuous", "sampled"), read_only=False),
        Param("substep", "double", 1e-3, "sampled form: longest integration sub-step (s)", min=1e-7,
              max=1.0, read_only=False),
        Param("max_sample_interval", "double", 0.0, "sampled form: the T_bar of (36) you expect, to "
              "check Theorem 2's condition T_bar mu < 1 (0: not checked)", min=0.0, read_only=False),
        Param("input_hold", "string", "zoh", "u between samples: held (zoh, like a DAC) or linear (foh)",
              choices=("zoh", "foh"), read_only=False),
        Param("state_map", "double_array", [], "n x n matrix P with x_plant = P [xi1; xi2] "
              "(empty: identity, x = [xi1; xi2])", read_only=False),
        Param("state_names", "string_array", [], "names of the plant states (empty: x0, x1, ...)"),
        Param("allow_unstable_internal", "bool", False, "accept A1 or -(A1^T + 2kI) with unstable "
              "modes: the internal states then grow exponentially (short runs only)", read_only=False),
    )

    def __init__(self, cfg: dict):
        self.form = Sampled if cfg["measurement"] == "sampled" else Continuous
        n1, q, m = cfg["n_unmeasured"], cfg["n_outputs"], cfg["n_inputs"]
        self.n1, self.q = n1, q
        self.n_states, self.n_outputs, self.n_inputs = n1 + q, q, m
        n = n1 + q
        A1 = matrix(cfg, "A1", n1, n1, P)
        A2 = matrix(cfg, "A2", q, n1, P)
        k, tau = cfg["k"], cfg["tau"]
        if k is None or k <= 0:
            raise ConfigError(P + "k", f"must be > 0, got {k}")
        if tau is None or tau <= 0:
            raise ConfigError(P + "tau", f"must be > 0 (it is the convergence time), got {tau}")
        if not STEP_QUANTUM <= tau <= MAX_TAU:
            raise ConfigError(P + "tau", f"must be between {STEP_QUANTUM:g} s (the runner's time "
                              f"quantum) and {MAX_TAU:g} s (the delay buffer holds tau seconds of "
                              f"samples), got {tau:g}")
        if observability_rank(A1, A2) < n1:
            raise ConfigError(P + "A2", "(A1, A2) is not observable: xi1 cannot be recovered from "
                              "the output (rank of the observability matrix < n1)")
        Ak = A1 + k * np.eye(n1)
        rate = float(np.max(np.abs(np.linalg.eigvals(Ak)))) * tau if np.all(np.isfinite(Ak)) else math.inf
        if not rate <= MAX_RATE_TAU:
            raise ConfigError(f"{P}k, {P}tau", f"|eig(A1 + kI)| tau = {rate:.4g} is beyond {MAX_RATE_TAU:g}: "
                              f"the design's integrals over [-tau, 0] (eq. 5) cannot be resolved in "
                              f"double precision (k = {k:g}, tau = {tau:g}); use a smaller tau or k")
        sv = np.linalg.svd(Ak, compute_uv=False)
        if sv[-1] <= 1e-9 * max(sv[0], 1.0):
            eig = np.linalg.eigvals(A1)
            raise ConfigError(P + "k", f"A1 + k I is singular: k = {k} equals -eigenvalue of A1 "
                              f"({', '.join(f'{-e:.6g}' for e in eig)}); pick another k")
        internal = np.concatenate([np.linalg.eigvals(A1), np.linalg.eigvals(-(A1.T + 2 * k * np.eye(n1)))])
        self.max_internal_rate = float(np.max(internal.real))
        if self.max_internal_rate > 0 and not cfg["allow_unstable_internal"]:
            need = float(-np.min(np.linalg.eigvals(A1).real) / 2)
            raise ConfigError(P + "k", f"the extension (7) has an unstable mode (rate "
                              f"{self.max_internal_rate:.4g}/s): its states grow without bound and "
                              f"overflow on a long run. Use k > {need:.4g} (so -(A1^T + 2kI) is Hurwitz)"
                              + (" and a Hurwitz A1" if np.max(np.linalg.eigvals(A1).real) > 0 else "")
                              + ", or set single_delay.allow_unstable_internal: true for short runs")
        F1, G = cfg["F1"] or ["0"] * n1, cfg["F2"] or ["0"] * q
        checked = {name: VectorFunction(texts, q, m, P + name, length=length)   # errors name F1[i]
                   for name, texts, length in (("F1", F1, n1), ("F2", G, q))}
        # the paper's F2 = G + k y (eq. 2): derived from k here, never written twice
        F2 = [f"({g}) + {float(k)!r}*y{i}" for i, g in enumerate(G)]
        # both in one compiled function: one call per evaluation on the hot path
        self.F = VectorFunction(F1 + F2, q, m, P + "F")
        ys = checked["F2"].y_syms
        self.F2_note = next((f"{P}F2[{i}] has the term {k:g}*y{i}, which the observer adds itself "
                             f"(F2 is the plant's own term G; an old config that wrote F2 = k y "
                             f"counts it twice)" for i, e in enumerate(checked["F2"].exprs)
                             if e.coeff(ys[i]).is_number and float(e.coeff(ys[i])) == k), None)
        if self.F2_note:
            warnings.warn(self.F2_note, ConfigNote, stacklevel=3)
        try:
            d = design(A1, A2, k, tau)
        except np.linalg.LinAlgError:
            d = {"cond_S": math.inf}
        if not np.isfinite(d["cond_S"]) or d["cond_S"] > 1e13:
            raise ConfigError(P + "tau", f"the Gramian S is numerically singular (cond(S) = "
                              f"{d['cond_S']:.3g}); change tau or k (cond(S) grows with (|A1| + k) tau)")
        err = quadrature_error(A1, A2, k, tau, d["S"], d["N"])
        if not err <= MAX_QUADRATURE_ERROR:
            raise ConfigError(f"{P}k, {P}tau", f"the design's integrals over [-tau, 0] are not resolved: "
                              f"refining the quadrature changes S or N by {err:.2g} (relative; at "
                              f"most {MAX_QUADRATURE_ERROR:g}); use a smaller tau or k (|eig(A1 + kI)| "
                              f"tau = {rate:.3g})")
        self.design = d
        self.A1, self.A2, self.k, self.tau = A1, A2, k, tau
        # Lipschitz constants of the paper's F1 and F2 = G + k y (eq. 3)
        self.K1, self.K2 = cfg["lipschitz_K1"], cfg["lipschitz_K2"] + k
        self.mu = theorem2_mu(d, A2, k, self.K1, self.K2)
        self.c_diamond = noise_bound_constant(d, tau, self.K1, self.K2)
        self.substep = cfg["substep"]
        self.T_bar = cfg["max_sample_interval"]
        self.foh_input = cfg["input_hold"] == "foh"

        if cfg["state_map"]:
            self.Pmap = matrix(cfg, "state_map", n, n, P)
            if np.linalg.matrix_rank(self.Pmap) < n:
                raise ConfigError(P + "state_map", "must be invertible")
        else:
            self.Pmap = np.eye(n)
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(n)]
        if len(self.state_names) != n:
            raise ConfigError(P + "state_names", f"expected {n} names, got {len(self.state_names)}")
        self.extension = extension(A1, A2, k, d)
        self._build()

    def _build(self) -> None:
        """The kernel's arrays (kernel.py has the layout)."""
        n1, q, m = self.n1, self.q, self.n_inputs
        ext = self.extension
        kern = self.form.KERNEL
        mats = {SD.C_PMAP: self.Pmap, SD.C_MD: ext["Md"], SD.C_MDA: ext["MdA"],
                SD.C_MDB: ext["MdB"], SD.C_ME: ext["Me"], SD.C_R: ext["R"], SD.C_A2: self.A2}
        mats.update(self.form.matrices(self))
        window = self.WINDOW_ENTRIES
        scalars = (self.k, self.tau, self.tau / continuous_form.FILL_POINTS, self.substep,
                   self.tau / window, window)
        c, ic, wk, size = SD.build(n1, q, m, self.foh_input, self.form.SAMPLED,
                                   self.form.max_step(self), scalars, mats,
                                   self.form.caches(self), SD.ring_capacity(window, kern.PUSHES),
                                   kern.scratch_floats(n1, q, m))
        ys, us = self.F.y_syms, self.F.u_syms
        self._build_kernel(c, ic, wk, size, models=(ModelFunction(self.F.exprs, [[], ys, us]),))
        self._st[K.GUARANTEED] = self.tau
        self._restart(None)

    #: entries of one delay window the ring keeps whole; a faster stream is thinned to
    #: entries tau / WINDOW_ENTRIES apart (the ring's memory is fixed: kernel.py)
    WINDOW_ENTRIES = 4096

    @property
    def KERNEL(self):          # noqa: N802  (KernelObserver's name for the kernel module)
        return self.form.KERNEL

    # -- what the state says ---------------------------------------------------------
    @property
    def _s(self) -> float | None:
        """Model time the observer's state is at (the last sample, or a later input of the
        sampled form); None before the first sample of a run."""
        return float(self._st[self._ic[SD.S_T]]) if self.started else None

    @property
    def last_substeps(self) -> int:
        """Predictor sub-steps the last call took (the sampled form; bounded by
        MAX_SUBSTEPS), 0 for the continuous form."""
        return sampled_form.last_substeps(self._wk, self._ic) if self.form.SAMPLED else 0

    @property
    def delay_entries(self) -> int:
        """Entries the delay ring holds."""
        o = self._ic[SD.S_RING]
        return int(self._st[o + 2] - self._st[o])

    def diagnostics(self):
        d = self.design
        out = {
            "form": self.form.NAME,
            "tau (guaranteed convergence time, s)": f"{self.tau:.6g}",
            "k": f"{self.k:.6g}",
            "cond(S)": f"{d['cond_S']:.4g}",
            "noise gain |R| + int|S^-1 (e^-kr - e^-(A1'+2k)r) H| dr": f"{d['noise_gain']:.4g}",
            "c_diamond (Theorem 1 bound, Remark 2)": f"{self.c_diamond:.4g}",
            "slowest internal mode (1/s)": f"{self.max_internal_rate:.4g}",
            **({"F2 note": self.F2_note} if self.F2_note else {}),
            "delay buffer entries": str(self.delay_entries),
        }
        if self.form.SAMPLED:
            out["Theorem 2 mu"] = f"{self.mu:.4g}"
            out["Theorem 2 needs T_bar <"] = f"{1.0 / self.mu:.4g} s"
            if self.T_bar > 0:
                out["Theorem 2 condition T_bar mu < 1"] = (
                    f"{'met' if self.T_bar * self.mu < 1 else 'NOT met'} (T_bar mu = {self.T_bar * self.mu:.3g})")
        return out


class Continuous:
    """Theorem 1: Y at every sample (continuous.py)."""

    KERNEL = continuous_form
    NAME = "continuous (Theorem 1)"
    SAMPLED = False

    @staticmethod
    def matrices(obs: SingleDelayObserver) -> dict:
        """{C_ index: matrix} of the form's own constants."""
        ext = obs.extension
        return {SD.C_A: ext["Az"], SD.C_B: ext["Bz"], SD.C_MO: readout(ext)}

    @staticmethod
    def caches(obs: SingleDelayObserver) -> list:
        """[(W_ index, slots, floats)] of the form's step caches."""
        return [(SD.W_CACHE, continuous_form.SLOTS, continuous_form.cache_size(obs.n1, obs.q))]

    @staticmethod
    def max_step(obs: SingleDelayObserver) -> float:
        """The longest interval the form bridges with bounded work (s)."""
        return math.inf


class Sampled:
    """Theorem 2: Y at sparse instants, the predictor between them (sampled.py); the
    runner's input messages advance it (ADVANCE)."""

    KERNEL = sampled_form
    NAME = "sampled (Theorem 2)"
    SAMPLED = True

    @staticmethod
    def matrices(obs: SingleDelayObserver) -> dict:
        before = predictor(obs.A2, obs.k, obs.extension, after=False)
        after = predictor(obs.A2, obs.k, obs.extension, after=True)
        return {SD.C_A: before[0], SD.C_B: before[1], SD.C_A_AFTER: after[0],
                SD.C_B_AFTER: after[1]}

    @staticmethod
    def caches(obs: SingleDelayObserver) -> list:
        size = sampled_form.cache_size(obs.n1, obs.q)
        return [(SD.W_CACHE, sampled_form.SLOTS, size),
                (SD.W_CACHE_AFTER, sampled_form.SLOTS, size)]

    @staticmethod
    def max_step(obs: SingleDelayObserver) -> float:
        # the predictor sub-steps the interval: at most MAX_SUBSTEPS of them
        return obs.substep * MAX_SUBSTEPS
