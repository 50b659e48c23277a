"""The baseline a user would pick instead: a Luenberger observer with output injection.

Plant ``x' = A x + B u + F(y, u)``, ``y = C x``, where F holds the known terms
that depend on the measured output and the input only (for the DC motor,
``-a1 sin(q)``).  Observer ``x_hat' = A x_hat + B u + F(y, u) + L (y - C x_hat)``:
the error obeys ``e' = (A - L C) e``, asymptotically, never in a guaranteed time.

L comes from pole placement (``design: poles``) or from the steady-state
Kalman filter (``design: kalman``, continuous algebraic Riccati equation with
diagonal process and measurement noise intensities).  The linear part is
integrated exactly (first-order hold of y and F between samples).
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solve_continuous_are

from ...core.expressions import VectorFunction
from ...core.linear import observability_rank, place_observer_poles
from ...core.model_code import ModelFunction
from ...core.step_cache import cache_floats, cache_init
from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param, matrix
from . import kernel

P = "luenberger."


class LuenbergerObserver(KernelObserver):
    TYPE = "luenberger"
    KERNEL = kernel
    DESCRIPTION = "Luenberger / steady-state Kalman baseline (asymptotic convergence only)"
    HEALTH_NAME = "slowest observer pole (1/s)"
    PARAMS = (
        Param("n_states", "int", 1, "plant order n", min=1, max=64),
        Param("n_outputs", "int", 1, "number of measured outputs p", min=1, max=64),
        Param("n_inputs", "int", 0, "number of known inputs m (0: no input topic needed)", min=0, max=64),
        Param("A", "double_array", None, "n x n state matrix, row-major", read_only=False),
        Param("B", "double_array", [], "n x m input matrix, row-major (empty: zeros)", read_only=False),
        Param("C", "double_array", None, "p x n output matrix, row-major", read_only=False),
        Param("F", "string_array", [], "n known terms in y0.. and u0.. (empty: zeros), e.g. '-35*sin(y0)'",
              read_only=False),
        Param("design", "string", "poles", "gain design", choices=("poles", "kalman"), read_only=False),
        Param("poles", "double_array", [], "n distinct negative real observer poles (design: poles)",
              read_only=False),
        Param("process_noise", "double_array", [], "n diagonal process noise intensities (design: kalman)",
              min=0.0, read_only=False),
        Param("measurement_noise", "double_array", [], "p diagonal measurement noise intensities "
              "(design: kalman)", min=0.0, read_only=False),
        Param("input_hold", "string", "zoh", "how u behaves between samples", choices=("zoh", "foh"),
              read_only=False),
        Param("initial_state", "string", "measurement", "where a (re)start without an explicit "
              "initial estimate begins: the state consistent with the first measurement (C^+ y: "
              "the measured states, zero for the rest) or zero (the old behaviour)",
              choices=("measurement", "zero"), read_only=False),
        Param("state_names", "string_array", [], "names of the n states (empty: x0, x1, ...)"),
    )

    def __init__(self, cfg: dict):
        n, p, m = cfg["n_states"], cfg["n_outputs"], cfg["n_inputs"]
        self.n_states, self.n_outputs, self.n_inputs = n, p, m
        A = matrix(cfg, "A", n, n, P)
        C = matrix(cfg, "C", p, n, P)
        B = np.zeros((n, m)) if not cfg["B"] else matrix(cfg, "B", n, m, P)
        self.F = VectorFunction(cfg["F"] or ["0"] * n, p, m, P + "F", length=n)
        if observability_rank(A, C) < n:
            raise ConfigError(P + "C", f"(A, C) is not observable: the observability matrix has rank "
                              f"{observability_rank(A, C)} < n = {n}")
        if cfg["design"] == "poles":
            L = place_observer_poles(A, C, cfg["poles"], P + "poles")
        else:
            q = np.asarray(cfg["process_noise"], dtype=float)
            r = np.asarray(cfg["measurement_noise"], dtype=float)
            if q.size != n:
                raise ConfigError(P + "process_noise", f"expected {n} values, got {q.size}")
            if r.size != p or np.any(r <= 0):
                raise ConfigError(P + "measurement_noise", f"expected {p} positive values, got {r.tolist()}")
            try:
                Pc = solve_continuous_are(A.T, C.T, np.diag(q), np.diag(r))
            except (ValueError, np.linalg.LinAlgError) as exc:
                raise ConfigError(P + "process_noise", f"the Riccati equation has no stabilising "
                                  f"solution ({exc}); is (A, sqrt(Q)) stabilisable?") from None
            L = Pc @ C.T @ np.diag(1.0 / r)
        self.L = L
        self.A, self.B, self.C = A, B, C
        Acl = A - L @ C
        eig = np.linalg.eigvals(Acl)
        if np.max(eig.real) >= 0:
            raise ConfigError(P + "design", f"A - L C is not Hurwitz (eigenvalues {eig})")
        self.closed_loop_poles = eig
        self.foh_input = cfg["input_hold"] == "foh"
        self.from_measurement = cfg["initial_state"] == "measurement"
        self.state_names = cfg["state_names"] or [f"x{i}" for i in range(n)]
        if len(self.state_names) != n:
            raise ConfigError(P + "state_names", f"expected {n} names, got {len(self.state_names)}")
        self._build(Acl, np.hstack([B, np.eye(n), L]))

    def _build(self, Acl: np.ndarray, Bw: np.ndarray) -> None:
        """The kernel's arrays (observers/luenberger/kernel.py has the layout)."""
        n, p, m = self.n_states, self.n_outputs, self.n_inputs
        w = m + n + p
        slots = 256
        c = np.concatenate(([np.inf], Acl.ravel(), Bw.ravel(), self.C.ravel(),
                            np.linalg.pinv(self.C).ravel()))
        cache = cache_floats(slots, n * (n + 2 * w))
        wk = np.zeros(cache + 2 * (n + 2 * w) + n + 2 * p)
        cache_init(wk, 0, slots)
        ic = K.layout_ic(n, K.HEADER, extra_ints=(n, p, m, int(self.foh_input), 0, slots, cache,
                                                    int(self.from_measurement)))
        model = ModelFunction(self.F.exprs, [[], self.F.y_syms, self.F.u_syms])
        self._build_kernel(c, ic, wk, K.HEADER + n + p + m + 1, models=(model,))
        self._st[K.HEALTH] = float(np.max(self.closed_loop_poles.real))
        self.reset(0.0)

    def diagnostics(self):
        return {
            "observer gain L": np.array2string(self.L.ravel(), precision=4),
            "closed-loop poles": ", ".join(f"{z:.4g}" for z in self.closed_loop_poles),
            "guarantee": "none (asymptotic)",
        }
