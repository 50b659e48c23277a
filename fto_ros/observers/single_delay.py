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

Continuous-measurement form (``measurement: continuous``, Theorem 1): the
linear extension is integrated exactly between samples (Y and F(Y, u) first-
order hold, u held or linear), the delayed combination of psi1, psi2 is kept in
a Hermite delay buffer, so irregular sampling is fine.  The only approximation
is the hold of Y between samples: O(h^2).

Sampled form (``measurement: sampled``, Theorem 2, eq. 39): Y only at sparse
instants t_j; between them the predictor omega' = A2 xi_e - k omega + F2(omega, u)
stands in for Y and is reset to Y(t_j) at each sample; integrated in sub-steps
of at most ``substep`` (exact linear part, Heun for the nonlinear F), and
advanced on every input message so fast inputs are not lost.

Before t0 + tau the estimate is the open-loop copy xh1 (no guarantee yet).
"""
from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.linalg import expm

from ..core.delay_buffer import DelayBuffer
from ..core.errors import ConfigNote
from ..core.discretize import MAX_SUBSTEPS, STEP_QUANTUM, ExactStepper, StepCache, quanta
from ..core.expressions import VectorFunction
from ..core.linear import observability_rank
from .base import ConfigError, Observer, Param, SampleRejected, matrix

P = "single_delay."
#: a step longer than tau / FILL_POINTS fills the delay buffer with at most this many exact
#: intermediate points over the last tau (bounded work per sample, whatever the gap)
FILL_POINTS = 16
#: the longest delay (s): the delay buffer holds tau seconds of samples
MAX_TAU = 3600.0
#: largest |eig(A1 + kI)| tau designed: beyond it e^{(A1 + kI) m} over [-tau, 0] has a
#: boundary layer the quadrature cannot see (and overflows further out)
MAX_RATE_TAU = 500.0
#: largest relative change of S, N when the quadrature is refined (quadrature_error)
MAX_QUADRATURE_ERROR = 1e-9


# ---------------------------------------------------------------------------
# design quantities of the paper (eq. 4-6, 11, 15, 38, 41)
# ---------------------------------------------------------------------------
def _gauss_legendre(a: float, b: float, panels: int = 16, order: int = 12):
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(a, b, panels + 1)
    mid = 0.5 * (edges[1:] + edges[:-1])[:, None]
    half = 0.5 * (edges[1:] - edges[:-1])[:, None]
    return (mid + half * x).ravel(), (half * w).ravel()


def _exp(x: float) -> float:
    """exp that saturates to inf: the paper's bounds overflow for large (|A1| + k) tau."""
    return math.exp(x) if x < 700 else math.inf


def gramian(A1: np.ndarray, A2: np.ndarray, k: float, tau: float, panels: int = 16):
    """(S, N, lambda at the nodes, nodes, weights): the integrals (5)-(6) over [-tau, 0] by
    composite Gauss-Legendre quadrature, ``panels`` panels of 12 nodes.  The matrix
    exponentials at all nodes are one batched ``expm`` call."""
    I = np.eye(A1.shape[0])
    Ak = A1 + k * I
    G = A2 @ np.linalg.inv(Ak)
    nodes, weights = _gauss_legendre(-tau, 0.0, panels)
    # lambda(m) = G (I - e^{Ak m}) at every node
    lam = G @ (I - expm(Ak * nodes[:, None, None]))                  # (nodes, q, n1)
    S = np.einsum("k,kqi,kqj->ij", weights, lam, lam)
    N = np.einsum("k,kqi->iq", weights, lam)
    return S, N, lam, nodes, weights


def quadrature_error(A1: np.ndarray, A2: np.ndarray, k: float, tau: float, S, N) -> float:
    """Relative change of S and N when the quadrature is refined (twice the panels): the
    a-posteriori error of the design's integrals.  The integrands are sums of exponentials
    e^{eig(A1 + kI) m}; 16 panels resolve them to ~1e-15 while |eig| tau is below ~100."""
    S2, N2, *_ = gramian(A1, A2, k, tau, panels=32)
    return max(float(np.linalg.norm(S - S2) / np.linalg.norm(S2)),
               float(np.linalg.norm(N - N2) / max(np.linalg.norm(N2), 1e-300)))


def design(A1: np.ndarray, A2: np.ndarray, k: float, tau: float) -> dict:
    """S, N, R, H, the decay matrices and the error-bound constants of the paper
    (the integrals: :func:`gramian`)."""
    n1 = A1.shape[0]
    I = np.eye(n1)
    Ak = A1 + k * I
    Aki = np.linalg.inv(Ak)
    G = A2 @ Aki
    S, N, lam, nodes, weights = gramian(A1, A2, k, tau)
    Sinv = np.linalg.inv(S)
    R = Sinv @ N
    H = Aki.T @ A2.T
    E1 = math.exp(-k * tau)
    E2 = expm(-(A1.T + 2 * k * I) * tau)
    norm = lambda M: float(np.linalg.norm(M, 2))  # noqa: E731
    exp = _exp
    lam_norm = np.linalg.norm(lam, 2, axis=(1, 2))
    Sbar, nA1, nA2, nH = norm(Sinv), norm(A1), norm(A2), norm(H)
    eA1 = exp(nA1 * tau)
    # Theorem 2 constants (38): integrals of |lambda(s)| times weights
    s1 = Sbar * nA2 * eA1 / k ** 2 * float(weights @ (lam_norm * (np.exp(k * nodes) - nodes * k - 1)))
    s2 = Sbar / k * float(weights @ (lam_norm * (1 - np.exp(k * nodes))))
    s3 = Sbar * tau * eA1 * nH * float(weights @ (lam_norm * (eA1 + np.exp(-k * nodes))))
    s4 = Sbar * nH * ((1 - math.exp(-k * tau)) / k + tau * exp(norm(A1.T + 2 * k * I) * tau))
    # linear L-infinity gain from the measurement noise delta2 to the estimate error
    # (the part of eq. 32 that does not go through F's Lipschitz constants, plus R delta2(t)):
    # |R| + int_0^tau |S^-1 (e^{-k r} I - e^{-(A1^T + 2kI) r}) H| dr
    r_nodes, r_w = _gauss_legendre(0.0, tau, panels=16, order=8)
    kern = Sinv @ ((np.exp(-k * r_nodes)[:, None, None] * I - expm(-(A1.T + 2 * k * I) * r_nodes[:, None, None])) @ H)
    noise_gain = norm(R) + float(r_w @ np.linalg.norm(kern, 2, axis=(1, 2)))
    beta_star = norm(G) * (1 + exp(norm(Ak) * tau))               # (16)
    beta_2star = 1 + exp(norm(A1.T + 2 * k * I) * tau)             # braces in (15)
    c_delta = tau * Sbar * nA2 * eA1 + Sbar * norm(G) * (eA1 + 1) * eA1  # (11)
    return dict(S=S, N=N, R=R, H=H, Sinv=Sinv, E1=E1, E2=E2, cond_S=float(np.linalg.cond(S)),
                Sbar=Sbar, sigma=(s1, s2, s3, s4), noise_gain=noise_gain, beta_star=beta_star,
                beta_2star=beta_2star, c_delta=c_delta)


def theorem2_mu(d: dict, A2: np.ndarray, k: float, K1: float, K2: float) -> float:
    """mu of (41): Theorem 2 needs T_bar * mu < 1 (a sufficient condition)."""
    s1, s2, s3, s4 = d["sigma"]
    q1 = (s1 + s3) * K1 + s2 * K2 + s4
    return float(np.linalg.norm(A2, 2)) * q1 + k + K2


def noise_bound_constant(d: dict, tau: float, K1: float, K2: float) -> float:
    """c_diamond of Remark 2: |xi1 - xi_e| <= c * sup|(eps1, eps2, delta2)| over the window."""
    return (tau ** 2 * d["beta_star"] * (d["c_delta"] * (K1 + 1) + d["Sbar"] * (K2 + 1))
            + d["Sbar"] * float(np.linalg.norm(d["H"], 2)) * d["beta_2star"] * tau)


class SingleDelayObserver(Observer):
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
        self.sampled = cfg["measurement"] == "sampled"
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
        self._build_matrices()
        self.buffer = DelayBuffer(n1)
        # a step longer than this is a gap whose delayed values are filled in (_fill)
        self._fill_step = tau / FILL_POINTS
        self._x_hat = np.zeros(n)
        self._health = 0.0
        self._residual = float("nan")

    # -- linear structure ------------------------------------------------------
    def _build_matrices(self) -> None:
        """State z = [xh1, xh2, psi1, psi2] (size N = 3 n1 + q), w = [F1, F2, Y] (n1 + 2q)."""
        n1, q, k, d = self.n1, self.q, self.k, self.design
        I1, Iq = np.eye(n1), np.eye(q)
        N = 3 * n1 + q
        sl = self.sl = dict(x1=slice(0, n1), x2=slice(n1, n1 + q), p1=slice(n1 + q, 2 * n1 + q),
                            p2=slice(2 * n1 + q, N))
        Az = np.zeros((N, N))
        Az[sl["x1"], sl["x1"]] = self.A1
        Az[sl["x2"], sl["x1"]] = self.A2
        Az[sl["x2"], sl["x2"]] = -k * Iq
        Az[sl["p1"], sl["x2"]] = -d["H"]
        Az[sl["p1"], sl["p1"]] = -k * I1
        Az[sl["p2"], sl["x2"]] = -d["H"]
        Az[sl["p2"], sl["p2"]] = -(self.A1.T + 2 * k * I1)
        Bz = np.zeros((N, n1 + 2 * q))
        Bz[sl["x1"], :n1] = I1
        Bz[sl["x2"], n1:n1 + q] = Iq
        Bz[sl["p1"], n1 + q:] = d["H"]
        Bz[sl["p2"], n1 + q:] = d["H"]
        self.Az, self.Bz = Az, Bz
        Sinv = d["Sinv"]
        # delayed combination dl(t) = S^-1 [e^{-k tau} psi1 - E2 psi2] and its derivative
        Md = np.zeros((n1, N))
        Md[:, sl["p1"]] = Sinv * d["E1"]
        Md[:, sl["p2"]] = -Sinv @ d["E2"]
        self.Md, self.MdA, self.MdB = Md, Md @ Az, Md @ Bz
        # current part: xi_e = Me z + R Y + dl(t - tau)
        Me = np.zeros((n1, N))
        Me[:, sl["x1"]] = I1
        Me[:, sl["x2"]] = -d["R"]
        Me[:, sl["p1"]] = -Sinv
        Me[:, sl["p2"]] = Sinv
        self.Me = Me
        self.R = d["R"]
        if not self.sampled:
            self.stepper = ExactStepper(Az, Bz)
            # everything an update needs from [z, w0, w1] in one product (see _fused)
            W = n1 + 2 * q
            Mo = np.zeros((3 * n1, N + W))
            Mo[:n1, :N] = Md
            Mo[n1:2 * n1, :N] = Md @ Az
            Mo[n1:2 * n1, N:] = Md @ Bz
            Mo[2 * n1:, :N] = Me
            Mo[2 * n1:, N + n1 + q:] = d["R"]
            self._Mo = Mo
            self._fused_cache = StepCache(self._fused)
            return
        # sampled form: Z = [z, omega]; v = [F1(omega,u), F2(omega,u), dl(t - tau)]
        # omega' = A2 xi_e - k omega + F2, xi_e = Me z + R omega + dl  (after t0 + tau)
        #        = A2 xh1 - k omega + F2                                (before: no delayed data)
        def augmented(after: bool):
            A = np.zeros((N + q, N + q))
            A[:N, :N] = Az
            A[:N, N:] = Bz[:, n1 + q:]                       # Y -> omega in the extension
            if after:
                A[N:, :N] = self.A2 @ Me
                A[N:, N:] = self.A2 @ d["R"] - k * Iq
            else:
                A[N:, sl["x1"]] = self.A2
                A[N:, N:] = -k * Iq
            B = np.zeros((N + q, 2 * n1 + q))
            B[:N, :n1 + q] = Bz[:, :n1 + q]
            B[N:, n1:n1 + q] = Iq
            if after:
                B[N:, n1 + q:] = self.A2
            return ExactStepper(A, B)
        self.stepper_before = augmented(False)
        self.stepper_after = augmented(True)

    # -- protocol ----------------------------------------------------------------
    # Model time s runs from 0 at the first sample after a (re)start (the base class's
    # clock): the delay buffer, the convergence test and the sampled predictor use it.
    def _restart(self, x0_hat):
        n1, q = self.n1, self.q
        xi = np.zeros(n1 + q) if x0_hat is None else np.linalg.solve(self.Pmap, x0_hat)
        self._z = np.zeros(3 * n1 + q)
        self._z[self.sl["x1"]] = xi[:n1]
        self._xi2_init = None if x0_hat is None else xi[n1:]
        self._s = None
        self._u = np.zeros(self.n_inputs)
        self.buffer.clear()
        self._residual = float("nan")
        self._health = 0.0

    def _w(self, y, u) -> np.ndarray:
        """w = [F1(y, u), F2(y, u), y] (one compiled call for F1 and F2); SampleRejected if
        the model terms are not finite there."""
        f = self.F(y, u)
        if not math.isfinite(sum(f)):
            raise SampleRejected("non_finite_model_term")
        return np.array(f + tuple(y))

    def _converged_at(self, s) -> bool:
        return s >= self.tau - 1e-9

    @property
    def max_step(self):
        # the sampled predictor sub-steps the interval: at most MAX_SUBSTEPS of them
        return self.substep * MAX_SUBSTEPS if self.sampled else math.inf

    def _first(self, y, u, gap):
        z = self._z.copy()
        # xh2(t0) = Y(t0) unless the user gave it: the innovation starts small
        z[self.sl["x2"]] = y if self._xi2_init is None else self._xi2_init
        w = self._w(y, u)
        self._z = z
        self.buffer.push(0.0, self.Md @ z, self.MdA @ z + self.MdB @ w)
        self._s, self._y, self._u, self._w_prev = 0.0, y, u, w
        self._omega = y.copy()
        self._xi_e = z[self.sl["x1"]].copy()
        self._publish(y)

    def _step(self, s, h, y, u):
        if self.sampled:
            self._update_sampled(s, y, u)
        else:
            self._update_continuous(s, h, y, u)

    def _fused(self, h: float) -> np.ndarray:
        """K(h) with K(h) [z; w0; w1] = [z(t+h); dl; d(dl)/dt; Me z + R Y] at t + h.

        The exact step and every linear read-out of the update in one
        matrix-vector product (cached per step size, like the step itself).
        """
        S_h = self.stepper.stacked(h)
        N, W = S_h.shape[0], self.n1 + 2 * self.q
        z_w1 = np.zeros((N + W, N + 2 * W))
        z_w1[:N] = S_h
        z_w1[N:, N + W:] = np.eye(W)
        return np.vstack([S_h, self._Mo @ z_w1])

    def _update_continuous(self, s, h, y, u):
        n1, N = self.n1, self._z.shape[0]
        u_end = u if self.foh_input else self._u
        w1 = self._w(y, u_end)
        w0 = self._w_prev
        mark = self.buffer.mark()
        z0, h_last = self._z, h
        if h > self._fill_step:
            # a gap: the reads at s' - tau for the next tau fall inside it, so fill the delay
            # buffer there with exact intermediate states (FOH of w over the gap, stepped in
            # whole quanta) instead of one Hermite segment across the whole gap
            k1 = quanta(s)
            try:
                z0, k0, w0 = self._fill(z0, quanta(self._s), k1, w0, w1)
            except SampleRejected:
                self.buffer.rewind(mark)
                raise
            h_last = (k1 - k0) * STEP_QUANTUM      # the last piece of the gap
        out = self._fused_cache(h_last) @ np.concatenate((z0, w0, w1))
        z = out[:N]
        dl_now = out[N:N + n1]
        ddl_now = out[N + n1:N + 2 * n1]
        if self._converged_at(s):
            dl_del = self.buffer.at(max(s - self.tau, self.buffer.first_time))
            xi_e = out[N + 2 * n1:] + dl_del
        else:
            dl_del = None
            xi_e = z[:n1]
        # a NaN or Inf anywhere in z or w reaches out (0 * nan is nan): one check covers all
        if not math.isfinite(out.sum()):
            self.buffer.rewind(mark)
            raise SampleRejected("non_finite_estimate")
        w_next = w1 if (u_end is u or np.array_equal(u, u_end)) else self._w(y, u)
        # one-step prediction of Y from the previous estimate: the residual
        ek = math.exp(-self.k * h)
        pred = ek * self._y + (1 - ek) / self.k * (self.A2 @ self._xi_e + self._w_prev[n1:n1 + self.q])
        r = y - pred
        self._residual = math.sqrt(r @ r)
        self.buffer.push(s, dl_now, ddl_now)
        self.buffer.trim()
        self._w_prev = w_next
        self._z, self._s, self._y, self._u, self._xi_e = z, s, y, u, xi_e
        self._health = 0.0 if dl_del is None else math.sqrt(dl_del @ dl_del)
        self._publish(y)

    def _fill(self, z, k0, k1, w0, w1):
        """Step z exactly from quanta k0 towards k1, pushing the delayed combination at
        points at most ``_fill_step`` apart over [k1 - tau, k1) (earlier ones would be
        trimmed at once), with w linear from w0 (at k0) to w1 (at k1).  Returns the
        state, its quanta and w at the last point, from where the final step goes to k1.
        At most FILL_POINTS + 1 steps, whatever the gap; SampleRejected (buffer pushes to
        be undone by the caller) if a value is not finite."""
        n1, N = self.n1, z.shape[0]
        a = max(k0, k1 - quanta(self.tau))
        m = min(max(1, math.ceil((k1 - a) * STEP_QUANTUM / self._fill_step)), FILL_POINTS, k1 - a)
        points = ([a] if a > k0 else []) + [a + round(j * (k1 - a) / m) for j in range(1, m)]
        for p in points:
            wp = w0 + (w1 - w0) * ((p - k0) / (k1 - k0))
            out = self._fused_cache((p - k0) * STEP_QUANTUM) @ np.concatenate((z, w0, wp))
            if not math.isfinite(out.sum()):
                raise SampleRejected("non_finite_estimate")
            z = out[:N]
            self.buffer.push(p * STEP_QUANTUM, out[N:N + n1], out[N + n1:N + 2 * n1])
            k0, w0 = p, wp
        return z, k0, w0

    # -- sampled form -----------------------------------------------------------
    def advance(self, t, u):
        """Sampled form: integrate the predictor up to t with the input (held, or linear
        to the new value with ``input_hold: foh``), then take u as the current input.

        Called by the runner on every input message, so an input faster than the sparse
        measurements is applied when it changes.  An interval the predictor cannot bridge
        (longer than ``max_step``) is not integrated: the next measurement is then a gap.
        """
        u = np.asarray(u, dtype=float)
        if not self.sampled or not self.started:
            return
        s = quanta(t - self._clock_t0) * STEP_QUANTUM
        if s < self._s:
            return
        if self._s < s <= self._s + self.max_step:
            self._z, self._omega, self._xi_e = self._integrate(s, u if self.foh_input else self._u)
            self._s = s
            self._publish(self._omega)
        self._u = u

    def _update_sampled(self, s, y, u):
        if s < self._s:
            # an input after this measurement already moved the prediction on
            raise SampleRejected("measurement_older_than_prediction")
        if s - self._s > self.max_step:
            raise SampleRejected("step_too_long")
        self._w(y, u)               # omega = y must give finite model terms (raises if not)
        z, omega, _ = self._integrate(s, self._u)
        self._residual = float(np.linalg.norm(y - omega))
        omega = y.copy()                                       # omega(t_j) = Y(t_j)
        mark = self.buffer.mark()
        xi_e = self._xi_e_sampled(s, z, omega)
        if not math.isfinite(xi_e.sum()):
            self.buffer.rewind(mark)
            raise SampleRejected("non_finite_estimate")
        self.buffer.trim()
        self._z, self._omega, self._xi_e, self._s, self._y, self._u = z, omega, xi_e, s, y, u
        self._publish(y)

    def _xi_e_sampled(self, s, z, omega):
        if not self._converged_at(s):
            return z[self.sl["x1"]].copy()
        dl = self.buffer.at(max(s - self.tau, self.buffer.first_time))
        self._health = float(np.linalg.norm(dl))
        return self.Me @ z + self.R @ omega + dl

    def _integrate(self, s_end, u_end):
        """(z, omega, xi_e) at s_end: sub-steps from self._s, exact linear part, Heun on F,
        the input linear from self._u to u_end.

        Pushes the delayed combination at every sub-step; on a non-finite value
        it undoes those pushes and raises SampleRejected, leaving the state as it was.
        """
        mark = self.buffer.mark()
        try:
            out = self._substeps(s_end, u_end)
        except SampleRejected:
            self.buffer.rewind(mark)
            raise
        if out is None:
            self.buffer.rewind(mark)
            raise SampleRejected("non_finite_prediction")
        return out

    def _delayed(self, s):
        if not self._converged_at(s):
            return np.zeros(self.n1)
        return self.buffer.at(max(s - self.tau, self.buffer.first_time))

    def _substeps(self, s_end, u_end):
        N = 3 * self.n1 + self.q
        s = s0 = self._s
        Z = np.concatenate((self._z, self._omega))
        u0 = self._u
        held = u_end is u0 or np.array_equal(u_end, u0)

        def u_at(t):
            return u0 if held else u0 + (u_end - u0) * ((t - s0) / (s_end - s0))
        # s_end == s0 when an input at the measurement's time already moved the prediction on;
        # sub-steps of whole quanta, so the exact steps come from cached matrices
        q0, q = quanta(s0), quanta(s_end) - quanta(s0)
        steps = 0 if q <= 0 else max(1, math.ceil(q * STEP_QUANTUM / self.substep - 1e-9))
        for i in range(steps):
            s_next = (q0 + round((i + 1) * q / steps)) * STEP_QUANTUM if i + 1 < steps else s_end
            after = self._converged_at(s)
            stepper = self.stepper_after if after else self.stepper_before
            v0 = np.concatenate((self._w(Z[N:], u_at(s))[:-self.q], self._delayed(s)))
            Zp = stepper.step(Z, v0, v0, s_next - s)
            if not math.isfinite(Zp.sum()):
                return None
            u_next = u_at(s_next)
            if self._converged_at(s_next) == after:
                v1 = np.concatenate((self._w(Zp[N:], u_next)[:-self.q], self._delayed(s_next)))
                Z = stepper.step(Z, v0, v1, s_next - s)
            else:
                Z = Zp
            if not math.isfinite(Z.sum()):
                return None
            z = Z[:N]
            w = self._w(Z[N:], u_next)
            self.buffer.push(s_next, self.Md @ z, self.MdA @ z + self.MdB @ w)
            s = s_next
        z, omega = Z[:N], Z[N:]
        xi_e = self._xi_e_sampled(s_end, z, omega)
        if not math.isfinite(xi_e.sum()):
            return None
        return z, omega, xi_e

    # -- outputs -------------------------------------------------------------------
    def _publish(self, xi2):
        self._x_hat = self.Pmap @ np.concatenate((self._xi_e, xi2))

    @property
    def estimate(self):
        return self._x_hat

    @property
    def guaranteed_time(self):
        return self.tau

    @property
    def health(self):
        return self._health

    def diagnostics(self):
        d = self.design
        out = {
            "form": "sampled (Theorem 2)" if self.sampled else "continuous (Theorem 1)",
            "tau (guaranteed convergence time, s)": f"{self.tau:.6g}",
            "k": f"{self.k:.6g}",
            "cond(S)": f"{d['cond_S']:.4g}",
            "noise gain |R| + int|S^-1 (e^-kr - e^-(A1'+2k)r) H| dr": f"{d['noise_gain']:.4g}",
            "c_diamond (Theorem 1 bound, Remark 2)": f"{self.c_diamond:.4g}",
            "slowest internal mode (1/s)": f"{self.max_internal_rate:.4g}",
            **({"F2 note": self.F2_note} if self.F2_note else {}),
            "delay buffer entries": str(len(self.buffer)),
        }
        if self.sampled:
            out["Theorem 2 mu"] = f"{self.mu:.4g}"
            out["Theorem 2 needs T_bar <"] = f"{1.0 / self.mu:.4g} s"
            if self.T_bar > 0:
                out["Theorem 2 condition T_bar mu < 1"] = (
                    f"{'met' if self.T_bar * self.mu < 1 else 'NOT met'} (T_bar mu = {self.T_bar * self.mu:.3g})")
        return out
