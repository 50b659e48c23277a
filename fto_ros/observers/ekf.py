"""Continuous-discrete extended Kalman filter: the baseline a user picks for a nonlinear plant.

Plant (written as text, like ``newton_inversion``, or derived from the plant block)::

    x' = f(x, u) + w(t),   E[w w'] = Qc delta    (Qc = diag(process_noise), continuous)
    y_k = h(x_k, u_k) + v_k,   E[v v'] = R       (R = diag(measurement_noise), per sample)

Jacobians A = df/dx and H = dh/dx by sympy, compiled once with the model (one plain-Python
function each for (f, A) and (h, H)).

**Prediction** over a sample interval h (split into equal sub-steps of at most ``max_step``,
at most :data:`MAX_SUBSTEPS`, each linearised at its start point x_a):  one matrix
exponential of the block matrix

    M = [[0,  0,  f(x_a, u)'],
         [0, -A,  Qc       ],
         [0,  0,  A'       ]] * dt

gives everything (Van Loan 1978): Phi = e^{A dt} (the transpose of the lower-right block),
Qd = integral_0^dt e^{A s} Qc e^{A' s} ds = Phi times the middle-right block, and the mean
increment integral_0^dt e^{A s} ds f(x_a, u) (the first row: the linearised exact step, also
called local linearisation).  The mean step is exact for a plant affine in the state with the
input held, so on a linear plant the filter is the exact discrete Kalman filter; on a
nonlinear plant its local error is O(dt^3) (the curvature of f).  ``input_hold: zoh`` holds
the input of the previous sample over the interval, ``foh`` uses the mean of the two.

**Correction** at the sample: innovation nu = y - h(x_pred, u), S = H P H' + R, the gain
K = P H' S^-1, the Joseph form P = (I - K H) P (I - K H)' + K R K', and the normalised
innovation squared NIS = nu' S^-1 nu (chi-square with p degrees of freedom, mean p, when the
noise settings are right): ``health``; the innovation and S are exposed for monitors.

The interval (a step h on the base class's 1 us clock, the first sample) comes from the
base class; :meth:`step` does one interval's prediction and correction and changes nothing,
so a sample that would give a non-finite state is rejected (SampleRejected) with the state
unchanged.
"""
from __future__ import annotations

import math

import numpy as np
import sympy
from scipy.linalg import expm

from ..core.expressions import compile_exprs
from ..core.named_model import parse_model
from .base import ConfigError, Observer, Param, SampleRejected

P = "ekf."
#: most sub-steps one sample interval is split into
MAX_SUBSTEPS = 100


class ExtendedKalmanFilter(Observer):
    TYPE = "ekf"
    DESCRIPTION = ("continuous-discrete extended Kalman filter: the baseline for nonlinear plants "
                   "(asymptotic, no guaranteed time)")
    HEALTH_NAME = "NIS = nu' S^-1 nu, the normalised innovation squared of the last update (mean p)"
    PARAMS = (
        Param("states", "string_array", None, "state names, e.g. [q, q_dot, current] (n = length)"),
        Param("inputs", "string_array", [], "known input names, e.g. [V] (m = length; [] for none)"),
        Param("constants", "string_array", [], "named constants 'name=value' usable in f and h"),
        Param("f", "string_array", None, "x' = f(x, u): one expression per state"),
        Param("h", "string_array", None, "y = h(x, u): one expression per measured output"),
        Param("process_noise", "double_array", None, "n diagonal intensities of the continuous "
              "process noise w (units^2/s): how far the model may be off", min=0.0,
              read_only=False),
        Param("measurement_noise", "double_array", None, "p variances of the measurement noise "
              "of one sample (units^2), > 0", min=0.0, read_only=False),
        Param("initial_covariance", "double_array", [], "n diagonal entries of P at every "
              "(re)start (empty: 1 each)", min=0.0, read_only=False),
        Param("input_hold", "string", "zoh", "u over a sample interval: the previous sample's "
              "(zoh, like a DAC) or the mean of both ends (foh)", choices=("zoh", "foh"),
              read_only=False),
        Param("max_step", "double", 0.01, "longest prediction sub-step (s): a longer interval is "
              "split into equal sub-steps, each linearised again (at most 100)", min=1e-6,
              read_only=False),
    )

    def __init__(self, cfg: dict):
        model = parse_model(cfg["states"], cfg["inputs"], cfg["f"], cfg["h"], cfg["constants"],
                            prefix=P)
        n, m, p = model.n, model.m, model.p
        self.n_states, self.n_outputs, self.n_inputs = n, p, m
        self.state_names = list(model.states)
        A = sympy.Matrix(model.f).jacobian(model.x)
        H = sympy.Matrix(model.h).jacobian(model.x)
        self._fA = compile_exprs(list(model.f) + list(A), (model.x, model.u))
        self._hH = compile_exprs(list(model.h) + list(H), (model.x, model.u))
        q = cfg["process_noise"]
        if q is None or len(q) != n:
            raise ConfigError(P + "process_noise", f"expected {n} intensities (one per state), "
                              f"got {'nothing' if q is None else len(q)}")
        r = cfg["measurement_noise"]
        if r is None or len(r) != p or min(r) <= 0:
            raise ConfigError(P + "measurement_noise", f"expected {p} positive variances (one per "
                              f"output), got {r}")
        p0 = cfg["initial_covariance"] or [1.0] * n
        if len(p0) != n or min(p0) <= 0:
            raise ConfigError(P + "initial_covariance", f"expected {n} positive values, got {p0}")
        self.Qc, self.R, self.P0 = np.diag(q), np.diag(r), np.diag(p0)
        self.foh_input = cfg["input_hold"] == "foh"
        self.sub_step = cfg["max_step"]
        self._M = np.zeros((2 * n + 1, 2 * n + 1))
        self._M[1:n + 1, n + 1:] = self.Qc
        self._I = np.eye(n)
        self.reset(0.0)

    # -- protocol -------------------------------------------------------------------
    def _restart(self, x0_hat):
        n = self.n_states
        self._x = np.zeros(n) if x0_hat is None else x0_hat.copy()
        self._P = self.P0.copy()
        self._u = None
        self._nu = self._S = None
        self._nis = math.nan
        self._nis_sum, self._updates = 0.0, 0
        self._residual = math.nan

    def _first(self, y, u, gap):
        self._take(0.0, y, u)                        # the first sample: a correction only

    def _step(self, s, h, y, u):
        self._take(h, y, u)

    def _take(self, h, y, u):
        x, Pm, nu, S, nis = self.step(h, y, u)
        self._x, self._P, self._nu, self._S, self._nis = x, Pm, nu, S, nis
        self._u = np.array(u, dtype=float)
        self._residual = float(np.linalg.norm(nu))
        self._nis_sum += nis
        self._updates += 1

    def step(self, h: float, y: np.ndarray, u: np.ndarray):
        """(x, P, innovation, S, NIS) after predicting over h and correcting with (y, u);
        no state changes.  SampleRejected when the result would not be finite."""
        x, Pm = self._x, self._P
        if h > 0.0:
            held = u if self._u is None else (0.5 * (self._u + u) if self.foh_input else self._u)
            k = min(MAX_SUBSTEPS, max(1, math.ceil(h / self.sub_step - 1e-9)))
            for _ in range(k):
                x, Pm = self._predict(x, Pm, held, h / k)
        try:
            vals = self._hH(x, u)
        except (ValueError, OverflowError, ZeroDivisionError, TypeError):
            raise SampleRejected("non_finite_model") from None
        p, n = self.n_outputs, self.n_states
        nu = y - np.array(vals[:p], dtype=float)
        H = np.array(vals[p:], dtype=float).reshape(p, n)
        PHt = Pm @ H.T
        S = H @ PHt + self.R
        try:
            Si = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            raise SampleRejected("singular_innovation_covariance") from None
        with np.errstate(all="ignore"):          # an overflow is caught just below
            K = PHt @ Si
            nis = float(nu @ Si @ nu)
            x = x + K @ nu
            IKH = self._I - K @ H
            Pm = IKH @ Pm @ IKH.T + K @ self.R @ K.T
            Pm = 0.5 * (Pm + Pm.T)
        if not math.isfinite(float(x.sum()) + float(Pm.sum()) + nis):   # one check for all
            raise SampleRejected("non_finite_estimate")
        return x, Pm, nu, S, nis

    def _predict(self, x, Pm, u, dt):
        """One linearised exact sub-step of length dt (see the module doc)."""
        n = self.n_states
        try:
            vals = self._fA(x, u)
        except (ValueError, OverflowError, ZeroDivisionError, TypeError):
            raise SampleRejected("non_finite_model") from None
        A = np.array(vals[n:], dtype=float).reshape(n, n)
        M = self._M.copy()
        M[0, n + 1:] = vals[:n]
        M[1:n + 1, 1:n + 1] = -A
        M[n + 1:, n + 1:] = A.T
        if not math.isfinite(float(M.sum())):
            raise SampleRejected("non_finite_model")
        E = expm(M * dt)
        Phi = E[n + 1:, n + 1:].T
        Qd = Phi @ E[1:n + 1, n + 1:]
        return x + E[0, n + 1:], Phi @ Pm @ Phi.T + 0.5 * (Qd + Qd.T)

    # -- outputs --------------------------------------------------------------------
    @property
    def estimate(self):
        return self._x

    @property
    def covariance(self) -> np.ndarray:
        """P, the error covariance of the last update (the filter's own account)."""
        return self._P

    @property
    def innovation(self) -> np.ndarray | None:
        """nu = y - h(x_pred, u) of the last update (None before one)."""
        return self._nu

    @property
    def innovation_covariance(self) -> np.ndarray | None:
        """S = H P H' + R of the last update (None before one)."""
        return self._S

    @property
    def nis(self) -> float:
        """nu' S^-1 nu of the last update (nan before one)."""
        return self._nis

    @property
    def health(self):
        return float(self._nis)

    def diagnostics(self):
        mean = self._nis_sum / self._updates if self._updates else math.nan
        return {
            "trace(P)": f"{float(np.trace(self._P)):.4g}",
            "NIS (last update)": f"{self._nis:.4g}",
            "NIS mean since reset": f"{mean:.4g} over {self._updates} updates (expected "
                                    f"{self.n_outputs} when the noise settings are right)",
            "prediction": "linearised exact step: one expm of the Van Loan block matrix per "
                          "sub-step (Phi, Qd and the mean)",
            "guarantee": "none (asymptotic, local)",
        }
