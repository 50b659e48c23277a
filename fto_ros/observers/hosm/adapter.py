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
The per-sample step is the compiled kernel (observers/hosm/kernel.py): it writes a candidate
state that is committed only when every value is finite, so a rejected sample leaves the
state, the differentiators' included, untouched.
"""
from __future__ import annotations

import math

import numpy as np

from ...core import differentiator as red
from ...core.discretize import MAX_SUBSTEPS
from ...core.expressions import VectorFunction
from ...core.layout import Layout
from ...core.linear import place_observer_poles
from ...core.model_code import ModelFunction
from ...core.step_cache import cache_floats, cache_init
from ...core.structure import StructureError, analyse, relative_degree
from .. import kernel as KP
from ..base import ConfigError, KernelObserver, Param, matrix
from . import kernel as K

P = "hosm."


def _fmt(z: np.ndarray) -> str:
    if len(z) == 0:
        return "none"
    out = []
    for v in z:
        v = complex(v)
        out.append(f"{v.real:.4g}" if abs(v.imag) < 1e-9 * max(1.0, abs(v)) else
                   f"{v.real:.4g}{v.imag:+.4g}j")
    return ", ".join(out)


class HosmObserver(KernelObserver):
    TYPE = "hosm"
    KERNEL = K
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
        self._diffs: list = []
        for i, order in enumerate(self.orders):
            if order == 0:
                self._diffs.append(None)     # r_i = 1, states only: v_i1 = y_i - c_i z itself
                continue
            gains = (red.recursive_to_nonrecursive(alphas[:order + 1]) if alphas else None)
            try:
                self._diffs.append(red.Differentiator(
                    order, float(M[i]), channels=1, scheme=scheme, rho=cfg["differentiator_rho"],
                    gains=gains, filter_order=cfg["differentiator_filter_order"],
                    max_step=cfg["differentiator_max_step"] or None))
            except ValueError as exc:
                raise ConfigError(P + _param_of(str(exc)), str(exc)) from None
        self.scheme = scheme
        self.n_zero = n - st.r_total
        self.foh_input = cfg["input_hold"] == "foh"
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(n)]
        if len(self.state_names) != n:
            raise ConfigError(P + "state_names", f"expected {n} names, got {len(self.state_names)}")
        self.unknown_input_names = cfg["unknown_input_names"] or [f"zeta{j}" for j in range(p)]
        if len(self.unknown_input_names) != p:
            raise ConfigError(P + "unknown_input_names", f"expected {p} names, got "
                              f"{len(self.unknown_input_names)}")
        self._build()

    def _build(self) -> None:
        """The kernel's arrays (observers/hosm/kernel.py has the layout)."""
        n, p, m = self.n_states, self.n_outputs, self.n_inputs
        st, nz, r = self.structure, self.n_zero, self.structure.r_total
        fzero = self.F.is_zero
        # F(y, u) without u: one evaluation per sample serves both ends of the step
        f_has_u = any(e.free_symbols & set(self.F.u_syms) for e in self.F.exprs)
        ncol = n + 2 * (m + p) + (0 if fzero else 2 * n)
        c, ic = Layout(1), {}                       # c[MAX_STEP] first
        for key, mat in ((K.CA, self.A), (K.CBW, np.hstack([self.B, np.eye(n), self.L])),
                         (K.CC, self.C), (K.CCPINV, np.linalg.pinv(self.C)),
                         (K.CTINV1, st.Tinv[:, :r]), (K.CTINV2, st.Tinv[:, r:]),
                         (K.CQINV, np.linalg.inv(st.Q)), (K.CG, st.G), (K.CA22, st.A22),
                         (K.CA21, st.A21)):
            ic[key] = c.put(mat)
        s = Layout(KP.HEADER)
        s.take(n + (p if self.identify else 0))     # x_hat, zeta
        for key, size in ((K.SZ, n), (K.SYT, p), (K.SY, p), (K.SU, m), (K.SF, n),
                          (K.SOM1, r), (K.SOM2, nz), (K.SHASX0, 1), (K.SX0, n)):
            ic[key] = s.take(size)
        per_out, scratch = [], 0
        for i, d in enumerate(self._diffs):
            blk = st.blocks[i]
            if d is None:
                per_out += [0, blk.start, blk.stop - blk.start, 0, 0]
                continue
            per_out += [d.order, blk.start, blk.stop - blk.start, c.put(d.consts),
                        s.take(d.state_size)]
            scratch = max(scratch, d.scratch_size)
        slots = 256
        w = Layout(0)
        ic[K.WK], ic[K.KSLOTS] = w.take(cache_floats(slots, 1 + n * ncol)), slots
        ic[K.WZ], ic[K.ZSLOTS] = w.take(cache_floats(slots, nz * (nz + 2 * r))), slots
        for key, size in ((K.WT1, n), (K.WTH, r + nz), (K.WGT, p), (K.WVB, p), (K.WF1, n),
                          (K.WV, ncol)):
            ic[key] = w.take(size)
        ic[K.WR] = w.take(max(scratch, 2 * (nz + 2 * r)))
        wk = np.zeros(w.size)
        cache_init(wk, ic[K.WK], slots)
        cache_init(wk, ic[K.WZ], slots)
        ints = [n, p, m, r, nz, int(self.identify), int(self.foh_input), int(fzero),
                int(f_has_u), ncol] + [ic[key] for key in range(K.CA, K.PER_OUT)] + [K.PER_OUT + 1]
        icv = KP.layout_ic(n, KP.HEADER, n_ui=p if self.identify else 0, ui=KP.HEADER + n,
                           extra_ints=ints + per_out)
        # differentiator sub-steps (differentiator_max_step) are bounded in number
        ms = [d.max_step for d in self._diffs if d is not None and d.max_step]
        c.data[KP.MAX_STEP] = min(ms) * MAX_SUBSTEPS if ms else math.inf
        model = ModelFunction(self.F.exprs, [[], self.F.y_syms, self.F.u_syms])
        self._build_kernel(c.array(), icv, wk, s.size, models=(model,))

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

    # -- views of the kernel's state and constants -------------------------------------------
    @property
    def diffs(self) -> list:
        """The differentiators (None for an output without one), as views of the state."""
        out = []
        for i, d in enumerate(self._diffs):
            b = self._ic[K.PER_OUT] + K.OUT_WIDTH * i
            out.append(None if d is None else d.on(self._st, int(self._ic[b + 4])))
        return out

    @property
    def differentiated_signal(self) -> np.ndarray:
        """e = y - C z at the last update: what differentiator i differentiates; its
        ``bounded_orders[i]``-th time derivative is what M[i] bounds."""
        n, p = self.n_states, self.n_outputs
        o = KP.HEADER + n + (p if self.identify else 0) + n
        return self._st[o:o + p].copy()

    @property
    def bounded_orders(self) -> list[int]:
        """Per output, the order of the derivative of e_i that M[i] bounds: the
        differentiator's order + 1 (r_i, or r_i + k + 1 when identifying)."""
        return [o + 1 for o in self.orders]

    def _const(self, key: int, rows: int, cols: int) -> np.ndarray:
        o = int(self._ic[key])
        return self._c[o:o + rows * cols].reshape(rows, cols)

    @property
    def Tinv1(self) -> np.ndarray:
        """The first r columns of T^-1 (a copy; assigning it changes the kernel's)."""
        return self._const(K.CTINV1, self.n_states, self.structure.r_total).copy()

    @Tinv1.setter
    def Tinv1(self, value) -> None:
        self._const(K.CTINV1, self.n_states, self.structure.r_total)[...] = value

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
