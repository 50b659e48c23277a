"""High-order sliding-mode observer with unknown-input identification (Fridman, Levant & Davila 2007).

Plant (eq. 1, 41), with known output/input terms F added (they cancel in the error):

    x' = A x + B u + F(y, u) + D zeta(t),   y = C x         (p outputs, p unknown inputs)

Observer (Sections 3-5):

    z' = A z + B u + F(y, u) + L (y - C z)                    Luenberger part (11), (32), (45)
    v_i = RED of order r_i - 1 (states only, (16), (35)) or r_i + k (identification, (26),
          (39), (52)) applied to y_i - c_i z                 differentiator part, one per output
    omega1 = (v_i,1 .. v_i,r_i)_i                             (27), (36), (53)
    omega2' = A21 omega1 + A22 omega2                         zero dynamics (37), (54)
    x_hat = z + T^-1 [omega1; omega2]                         (15), (28), (37), (55)
    zeta_hat = Q^-1 (v_bar - G [omega1; omega2])              (29), (40), (56)

T = [T1; T2]: T1 stacks c_i (A - LC)^j, j < r_i (so T = P~ of eq. (14) when r = n), T2 a
complement with T2 D = 0 (core/structure.py); v_bar_i = v_i,r_i+1 (the r_i-th derivative
estimate); G_i = c_i (A - LC)^(r_i) T^-1, i.e. the paper's a_1..a_n of (29) when r = n.  In the
strongly detectable case the paper's (40) drops the a_(r+1).. theta2 terms; they are kept here
(the proof of Theorem 4.4 has them), which makes zeta_hat asymptotically exact.

Discretisation (sample-driven, any step):
- the Luenberger part is integrated exactly with the OUTPUT ERROR y - C z first-order held
  between samples (implicit in z at the new sample, a linear solve cached per step size):
  the injection then only errs by O(h^2 |e''|), bounded, instead of O(h^2 |y''|), which grows
  with an unstable plant's output (the paper's Theorem 3.7 argument: sample the error, not y);
  B u is held (zoh) or linear (foh), F(y, u) first-order held;
- the differentiator is core/differentiator.py (eigenvalue-matched by default: no chattering,
  keeps the h^(N-i) accuracy orders);
- omega2 is integrated exactly with omega1 linear between samples.
Updates are transactional: the differentiators are restored when a later part fails.
"""
from __future__ import annotations

import math

import numpy as np

from ..core import differentiator as red
from ..core.discretize import MAX_SUBSTEPS, ExactStepper, StepCache
from ..core.expressions import VectorFunction
from ..core.linear import place_observer_poles
from ..core.structure import StructureError, analyse, relative_degree
from .base import ConfigError, Observer, Param, SampleRejected, matrix

P = "hosm."
_CACHE = 256


def _fmt(z: np.ndarray) -> str:
    if len(z) == 0:
        return "none"
    out = []
    for v in z:
        v = complex(v)
        out.append(f"{v.real:.4g}" if abs(v.imag) < 1e-9 * max(1.0, abs(v)) else
                   f"{v.real:.4g}{v.imag:+.4g}j")
    return ", ".join(out)


class HosmObserver(Observer):
    TYPE = "hosm"
    DESCRIPTION = ("Fridman, Levant & Davila 2007: high-order sliding-mode observer, exact in finite "
                   "time under a bounded unknown input, which it identifies")
    HEALTH_NAME = "largest differentiator residual |y_i - c_i z - v_i1|"
    PARAMS = (
        Param("n_states", "int", None, "plant order n", min=1, max=32),
        Param("n_outputs", "int", 1, "number of measured outputs p (= number of unknown inputs)",
              min=1, max=8),
        Param("n_inputs", "int", 0, "number of known inputs m (0: no input topic needed)", min=0, max=32),
        Param("A", "double_array", None, "n x n state matrix, row-major", read_only=False),
        Param("B", "double_array", [], "n x m known-input matrix, row-major (empty: zeros)",
              read_only=False),
        Param("C", "double_array", None, "p x n output matrix, row-major", read_only=False),
        Param("D", "double_array", None, "n x p unknown-input matrix, row-major (zeta enters as D zeta)",
              read_only=False),
        Param("F", "string_array", [], "n known terms in y0.. and u0.. added to A x + B u (empty: "
              "zeros), e.g. '-35*sin(y0)'", read_only=False),
        Param("L", "double_array", [], "n x p Luenberger gain of (11), row-major; A - L C must be "
              "Hurwitz (empty: from 'poles')", read_only=False),
        Param("poles", "double_array", [], "n distinct negative real poles of A - L C (used when L is "
              "empty; needs (A, C) observable)", read_only=False),
        Param("M", "double_array", None, "per output (1 value: all outputs), a bound on the "
              "N-th time derivative of the output error e_i = y_i - c_i z that differentiator i "
              "differentiates, in y_i's units per s^N, N = r_i (states only) or r_i + k + 1 "
              "(identification): for a joint angle (rad) driven by an unknown torque (r = 2), "
              "rad/s^2 (the acceleration the unknown input causes) or, with k = 0, rad/s^3 (how "
              "fast that acceleration changes). The paper needs M > |d| zeta+ or M > |d| "
              "sup|zeta^(k+1)|; fto-design --suggest-from BAG measures it on a recording",
              min=1e-12, read_only=False),
        Param("identify_unknown_input", "bool", True, "estimate zeta too (eq. 26-29, 39-40, 56): the "
              "differentiator order becomes r_i + k instead of r_i - 1", read_only=False),
        Param("smoothness_order", "int", 0, "k of Assumption 3.3: zeta^(k) is Lipschitz (its "
              "(k+1)-th derivative bounded); used when identify_unknown_input", min=0, max=6,
              read_only=False),
        Param("unknown_input_bound", "double_array", [], "zeta+ per unknown input, |zeta_j| <= "
              "zeta+_j, to check M against the paper's bound (empty: not checked)", min=0.0,
              read_only=False),
        Param("unknown_input_derivative_bound", "double_array", [], "bound of |zeta_j^(k+1)| per "
              "unknown input, to check M when identifying (empty: not checked)", min=0.0,
              read_only=False),
        Param("differentiator_scheme", "string", "eigenvalue_matched", "discretisation of the "
              "differentiator", choices=red.SCHEMES, read_only=False),
        Param("differentiator_rho", "double", 2.0, "eigenvalue_matched: pole radius factor rho "
              "(r = rho M^(1/N)); 1.5..3 works", min=1e-3, max=100.0, read_only=False),
        Param("differentiator_gains", "double_array", [], "livne_levant / euler: the paper's "
              "recursive alpha_1, alpha_2, ... (alpha_1 = 1.1 in the last equation); empty: 1.1, "
              "1.5, 2, 3, 5, 7, 10, 12", min=1e-6, read_only=False),
        Param("differentiator_filter_order", "int", 0, "eigenvalue_matched: extra filtering "
              "integrators against noise (0: none)", min=0, max=4, read_only=False),
        Param("differentiator_max_step", "double", 0.0, "split longer steps into sub-steps of at "
              "most this (s) in the differentiator (0: never)", min=0.0, read_only=False),
        Param("input_hold", "string", "zoh", "known input u between samples: held (zoh, like a DAC) "
              "or linear (foh)", choices=("zoh", "foh"), read_only=False),
        Param("state_names", "string_array", [], "names of the n states (empty: x0, x1, ...)"),
        Param("unknown_input_names", "string_array", [], "names of the p unknown inputs (empty: "
              "zeta0, zeta1, ...)"),
    )

    def __init__(self, cfg: dict):
        n, p, m = cfg["n_states"], cfg["n_outputs"], cfg["n_inputs"]
        if n is None:
            raise ConfigError(P + "n_states", "missing: the plant order n is required")
        self.n_states, self.n_outputs, self.n_inputs = n, p, m
        A = matrix(cfg, "A", n, n, P)
        C = matrix(cfg, "C", p, n, P)
        D = matrix(cfg, "D", n, p, P)
        B = np.zeros((n, m)) if not cfg["B"] else matrix(cfg, "B", n, m, P)
        if np.linalg.norm(D) == 0:
            raise ConfigError(P + "D", "is zero: with no unknown input use the luenberger observer")
        self.F = VectorFunction(cfg["F"] or ["0"] * n, p, m, P + "F", length=n)
        # relative degree first: it decides everything else
        try:
            r, _ = relative_degree(A, C, D)
        except StructureError as exc:
            raise ConfigError(P + "D", str(exc)) from None
        if cfg["L"]:
            L = matrix(cfg, "L", n, p, P)
        elif cfg["poles"]:
            L = place_observer_poles(A, C, cfg["poles"], P + "poles")
        else:
            raise ConfigError(P + "L", "give the Luenberger gain L or the poles of A - L C")
        try:
            st = analyse(A, C, D, L)
        except StructureError as exc:
            raise ConfigError(P + ("L" if exc.condition == "luenberger" else "D"), str(exc)) from None
        self.structure = st
        self.A, self.B, self.C, self.D, self.L = A, B, C, D, L
        self.closed_loop_poles = np.linalg.eigvals(A - L @ C)

        # differentiators, one per output
        M = np.asarray(cfg["M"] if cfg["M"] is not None else [], dtype=float)
        if M.size == 1:
            M = np.full(p, float(M[0]))
        if M.size != p:
            raise ConfigError(P + "M", f"expected 1 or {p} values, got {M.size}")
        self.M = M
        self.identify = bool(cfg["identify_unknown_input"])
        k = cfg["smoothness_order"]
        self.k = k
        self.orders = [ri + k if self.identify else ri - 1 for ri in r]
        if max(self.orders) > red.MAX_ORDER:
            raise ConfigError(P + ("smoothness_order" if self.identify else "D"),
                              f"the differentiator order r_i {'+ k' if self.identify else '- 1'} = "
                              f"{max(self.orders)} exceeds {red.MAX_ORDER}")
        self._check_M(cfg)
        scheme = cfg["differentiator_scheme"]
        alphas = cfg["differentiator_gains"]
        if alphas and scheme == "eigenvalue_matched":
            raise ConfigError(P + "differentiator_gains", "the eigenvalue_matched scheme places its "
                              "poles from rho and M; gains apply to livne_levant and euler only")
        if alphas and len(alphas) < max(self.orders) + 1:
            raise ConfigError(P + "differentiator_gains", f"need at least {max(self.orders) + 1} "
                              f"values alpha_1..alpha_N, got {len(alphas)}")
        self.diffs: list = []
        for i, order in enumerate(self.orders):
            if order == 0:
                self.diffs.append(None)      # r_i = 1, states only: v_i1 = y_i - c_i z itself
                continue
            gains = (red.recursive_to_nonrecursive(alphas[:order + 1]) if alphas else None)
            try:
                self.diffs.append(red.Differentiator(
                    order, float(M[i]), channels=1, scheme=scheme, rho=cfg["differentiator_rho"],
                    gains=gains, filter_order=cfg["differentiator_filter_order"],
                    max_step=cfg["differentiator_max_step"] or None))
            except ValueError as exc:
                raise ConfigError(P + _param_of(str(exc)), str(exc)) from None
        self.scheme = scheme

        # Luenberger part: z' = A_lc... no: z' = A z + B u + F + L w, w = y - C z FOH, implicit in z
        self.stepper = ExactStepper(A, np.hstack([B, np.eye(n), L]))
        self._zcache = StepCache(self._step_matrix)
        nz = n - st.r_total
        self.n_zero = nz
        self.zstepper = ExactStepper(st.A22, st.A21) if nz else None
        self.Tinv1 = st.Tinv[:, :st.r_total].copy()
        self.Tinv2 = st.Tinv[:, st.r_total:].copy()
        self.Qinv = np.linalg.inv(st.Q)
        self.G = st.G
        self.foh_input = cfg["input_hold"] == "foh"
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(n)]
        if len(self.state_names) != n:
            raise ConfigError(P + "state_names", f"expected {n} names, got {len(self.state_names)}")
        self.unknown_input_names = cfg["unknown_input_names"] or [f"zeta{j}" for j in range(p)]
        if len(self.unknown_input_names) != p:
            raise ConfigError(P + "unknown_input_names", f"expected {p} names, got "
                              f"{len(self.unknown_input_names)}")
        self._siso = p == 1
        self._Fzero = self.F.is_zero
        # F(y, u) without u: one evaluation per sample serves both ends of the step
        self._F_has_u = any(e.free_symbols & set(self.F.u_syms) for e in self.F.exprs)
        self._zeros_n = np.zeros(n)
        self._vbar = np.zeros(p)
        self._Cpinv = np.linalg.pinv(C)
        self._x0 = None
        self._x_hat = np.zeros(n)
        self._zeta = np.zeros(p) if self.identify else None

    # -- checks -----------------------------------------------------------------------------
    def _check_M(self, cfg) -> None:
        """M against the bound the paper states (Theorem 3.4: M > |d| zeta+; (26): M > sup|.^(n+k+1)|)."""
        p = self.n_outputs
        Qabs = np.abs(self.structure.Q)
        name = "unknown_input_derivative_bound" if self.identify else "unknown_input_bound"
        bound = cfg[name]
        self.M_check = "not checked (set hosm." + name + ")"
        if not bound:
            return
        b = np.asarray(bound, dtype=float)
        if b.size == 1:
            b = np.full(p, float(b[0]))
        if b.size != p:
            raise ConfigError(P + name, f"expected 1 or {p} values, got {b.size}")
        need = Qabs @ b
        what = "sup|zeta^(k+1)|" if self.identify else "zeta+"
        for i in range(p):
            if not self.M[i] > need[i]:
                N = self.bounded_orders[i]
                raise ConfigError(P + "M", f"M[{i}] = {self.M[i]:g} is too small: the paper needs "
                                  f"M > sum_j |d_ij| {what}_j = {need[i]:.6g} for output {i} "
                                  f"(d = c_i A^(r_i-1) D); M[{i}] bounds d^{N}/dt^{N} of output "
                                  f"{i}'s error y{i} - c{i} z, in y{i}'s units per s^{N} "
                                  f"(rad/s^{N} for a joint angle)")
        self.M_check = "; ".join(f"M[{i}] = {self.M[i]:g} > {need[i]:.4g} = |d| {what}"
                                 for i in range(p))

    @property
    def max_step(self):
        # differentiator sub-steps (differentiator_max_step) are bounded in number
        ms = [d.max_step for d in self.diffs if d is not None and d.max_step]
        return min(ms) * MAX_SUBSTEPS if ms else math.inf

    def _step_matrix(self, h: float) -> np.ndarray:
        """K_h with z_new = K_h @ [z, u0, F0, w0, u1, F1, y1] (error FOH, solved for z_new);
        None when the implicit step is singular at this h."""
        n, m, p = self.n_states, self.n_inputs, self.n_outputs
        S = self.stepper.stacked(h)               # [Phi | G0 | G1], w = [u, F, ytilde]
        w = m + n + p
        Phi, G0, G1 = S[:, :n], S[:, n:n + w], S[:, n + w:]
        G1L = G1[:, m + n:]
        Mimp = np.eye(n) + G1L @ self.C
        if np.linalg.cond(Mimp) > 1e12:
            return None
        if self.F.is_zero:      # no F columns: [z, u0, w0, u1, y1]
            blocks = [Phi, G0[:, :m], G0[:, m + n:], G1[:, :m], G1L]
        else:
            blocks = [Phi, G0, G1[:, :m + n], G1L]
        return np.linalg.solve(Mimp, np.hstack(blocks))

    # -- protocol ---------------------------------------------------------------------------
    def _restart(self, x0_hat):
        # no initial estimate: z starts at the least-norm state consistent with the first
        # sample (z0 = C^+ y0, set in _first), so the output error starts at zero
        self._x0 = x0_hat

    def _gather(self, ytil, v_list):
        """(omega1, v_bar) from the output error and the differentiators' estimates."""
        st = self.structure
        om1 = np.empty(st.r_total)
        vbar = self._vbar
        for i, blk in enumerate(st.blocks):
            v = v_list[i]
            ri = blk.stop - blk.start
            if v is None:
                om1[blk] = ytil[i]
            else:
                om1[blk] = v[:ri]
                if self.identify:
                    vbar[i] = v[ri]
        return om1, vbar

    def _finish(self, z, om1, vbar, omega2):
        """(x_hat, zeta_hat) from z, omega1, v_bar and omega2."""
        x_hat = z + self.Tinv1 @ om1
        if self.n_zero:
            x_hat += self.Tinv2 @ omega2
            theta = np.concatenate((om1, omega2))
        else:
            theta = om1
        zeta = self.Qinv @ (vbar - self.G @ theta) if self.identify else None
        return x_hat, zeta

    def _model_term(self, y, u):
        if self._Fzero:
            return self._zeros_n
        return np.array(self.F(y, u), dtype=float)

    def _step(self, s, h, y, u):
        u_end = u if self.foh_input else self._u
        F1 = self._model_term(y, u_end)
        K = self._zcache(h)
        if K is None:
            raise SampleRejected("singular_step")
        if self._Fzero:
            z = K @ np.concatenate((self._z, self._u, self._ytil, u_end, y))
        else:
            z = K @ np.concatenate((self._z, self._u, self._F, self._ytil, u_end, F1, y))
        ytil = y - self.C @ z
        diffs = self.diffs
        if self._siso:
            d = diffs[0]
            if d is None:
                v_list = (None,)
                saved = None
            else:
                saved = d.get_state()
                try:
                    v_list = (d.update(h, ytil)[0],)
                except ValueError:
                    d.set_state(saved)
                    raise SampleRejected("non_finite_estimate") from None
        else:
            saved = [None if d is None else d.get_state() for d in diffs]
            v_list = []
            try:
                for i, d in enumerate(diffs):
                    v_list.append(None if d is None else d.update(h, ytil[i:i + 1])[0])
            except ValueError:
                self._restore(saved)
                raise SampleRejected("non_finite_estimate") from None
        om1, vbar = self._gather(ytil, v_list)
        if self.n_zero:
            omega2 = self.zstepper.step(self._omega2, self._om1, om1, h)
        else:
            omega2 = self._omega2
        x_hat, zeta = self._finish(z, om1, vbar, omega2)
        F_now = F1 if (self.foh_input or not self._F_has_u) else self._model_term(y, u)
        check = float(x_hat.sum()) + float(z.sum()) + float(omega2.sum()) + float(F_now.sum())
        if zeta is not None:
            check += float(zeta.sum())
        if not math.isfinite(check):
            self._restore(saved)
            raise SampleRejected("non_finite_estimate")
        self._y, self._u, self._F = y, u, F_now
        self._z, self._ytil, self._om1, self._omega2 = z, ytil, om1, omega2
        self._x_hat, self._zeta = x_hat, zeta

    def _restore(self, saved) -> None:
        if self._siso:
            saved = [saved]
        for d, s_ in zip(self.diffs, saved):
            if d is not None and s_ is not None:
                d.set_state(s_)

    def _first(self, y, u, gap) -> None:
        """The first sample after reset: z = x0_hat, differentiators start at y - C z."""
        Fy = self._model_term(y, u)
        if not math.isfinite(float(Fy.sum())):
            raise SampleRejected("non_finite_model_term")
        z = self._Cpinv @ y if self._x0 is None else self._x0.copy()
        ytil = y - self.C @ z
        v_list = []
        for i, d in enumerate(self.diffs):
            if d is None:
                v_list.append(None)
            else:
                d.reset(ytil[i:i + 1])
                v_list.append(d.estimates[0])
        omega2 = np.zeros(self.n_zero)
        om1, vbar = self._gather(ytil, v_list)
        x_hat, zeta = self._finish(z, om1, vbar, omega2)
        self._y, self._u, self._F = y, u, Fy
        self._z, self._ytil, self._om1, self._omega2 = z, ytil, om1, omega2
        self._x_hat, self._zeta = x_hat, zeta

    # -- outputs ----------------------------------------------------------------------------
    @property
    def estimate(self):
        return self._x_hat

    @property
    def differentiated_signal(self) -> np.ndarray:
        """e = y - C z at the last update: what differentiator i differentiates; its
        ``bounded_orders[i]``-th time derivative is what M[i] bounds."""
        return self._ytil.copy()

    @property
    def bounded_orders(self) -> list[int]:
        """Per output, the order of the derivative of e_i that M[i] bounds: the
        differentiator's order + 1 (r_i, or r_i + k + 1 when identifying)."""
        return [o + 1 for o in self.orders]

    @property
    def unknown_input(self):
        return self._zeta

    @property
    def output_residual(self):
        if not self.started:
            return float("nan")
        r = self._y - self.C @ self._x_hat
        return float(math.sqrt(float(r @ r)))

    @property
    def health(self):
        res = [float(d.residual[0]) for d in self.diffs if d is not None]
        return max(res) if res else 0.0

    def diagnostics(self):
        st = self.structure
        kind = ("strongly observable (r = n): state exact in finite time" if st.strongly_observable
                else f"strongly detectable (r = {st.r_total} < n = {self.n_states}): first "
                     f"{st.r_total} canonical coordinates exact in finite time, the rest asymptotic")
        out = {
            "relative degree": ", ".join(str(v) for v in st.r),
            "invariant zeros": _fmt(st.zeros),
            "structure": kind,
            "observability index n_O": st.n_observable,
            "M": ", ".join(f"{v:g}" for v in self.M),
            "M bounds": ", ".join(f"|d^{N}/dt^{N} (y{i} - c{i} z)| (units of y{i} per s^{N})"
                                  for i, N in enumerate(self.bounded_orders)),
            "M check": self.M_check,
            "differentiator": f"{self.scheme}, order(s) {', '.join(str(o) for o in self.orders)}",
            "differentiator residual": f"{self.health:.3g}",
            "Luenberger poles": _fmt(self.closed_loop_poles),
            "unknown input": (f"identified (k = {self.k})" if self.identify else "not identified"),
            "guarantee": "finite time, no a-priori bound on the transient",
        }
        return out


def _param_of(message: str) -> str:
    for key, name in (("rho", "differentiator_rho"), ("gains", "differentiator_gains"),
                      ("filter_order", "differentiator_filter_order"),
                      ("max_step", "differentiator_max_step"), ("scheme", "differentiator_scheme"),
                      ("L:", "M")):
        if message.startswith(key) or key in message.split(":")[0]:
            return name
    return "differentiator_scheme"
