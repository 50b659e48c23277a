"""Continuous-discrete extended Kalman filter: the baseline a user picks for a nonlinear plant.

Plant (written as text, like ``newton_inversion``, or derived from the plant block)::

    x' = f(x, u) + w(t),   E[w w'] = Qc delta    (Qc = diag(process_noise), continuous)
    y_k = h(x_k, u_k) + v_k,   E[v v'] = R       (R = diag(measurement_noise), per sample)

Jacobians A = df/dx and H = dh/dx by sympy, compiled with the model (core/model_code.py:
one model function for (f, A), one for (h, H)).

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

The per-sample work is the kernel (kernel.py); a sample that would give a non-finite state
is rejected with the state unchanged (``non_finite_model`` where f or h is not finite at the
estimate, ``singular_innovation_covariance``, ``non_finite_estimate``).
"""
from __future__ import annotations

import math

import numpy as np
import sympy

from ...core.model_code import ModelFunction
from ...core.named_model import parse_model
from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param, RestartCovariance
from . import kernel
from .kernel import MAX_SUBSTEPS, SUB_STEP

P = "ekf."

__all__ = ["ExtendedKalmanFilter", "MAX_SUBSTEPS"]


class ExtendedKalmanFilter(RestartCovariance, KernelObserver):
    TYPE = "ekf"
    KERNEL = kernel
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
        Param("initial_state", "string", "measurement", "where a (re)start without an explicit "
              "initial estimate begins: the state consistent with the first measurement (least "
              "squares on h, zero for unmeasured states, P saying so) or zero with P0 (the old "
              "behaviour)", choices=("measurement", "zero"), read_only=False),
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
        self.Qc, self.R = np.diag(q), np.diag(r)
        self.foh_input = cfg["input_hold"] == "foh"
        self.sub_step = cfg["max_step"]
        groups = [model.x, [], model.u]
        models = (ModelFunction(list(model.f) + list(A), groups),
                  ModelFunction(list(model.h) + list(H), groups))
        offs, size = kernel.layout(n, p, m)
        ic = K.layout_ic(n, K.HEADER, extra_ints=[n, p, m, int(self.foh_input)] + offs
                          + [int(cfg["initial_state"] == "measurement")])
        c = np.concatenate(([math.inf, self.sub_step], self.Qc.ravel(), self.R.ravel(),
                            np.diag(p0).ravel()))
        self._build_kernel(c, ic, np.zeros(0), size, models=models)
        self.reset(0.0)

    def _slice(self, which: int, size: int) -> np.ndarray:
        o = int(self._ic[which])
        return self._st[o:o + size]

    # -- outputs --------------------------------------------------------------------
    def _p0(self) -> np.ndarray:
        """The (re)start covariance in the constants (kernel.py's layout)."""
        n = self.n_states
        o = SUB_STEP + 1 + n * n + self.n_outputs ** 2
        return self._c[o:o + n * n].reshape(n, n)

    @property
    def covariance(self) -> np.ndarray:
        """P, the error covariance of the last update (the filter's own account)."""
        n = self.n_states
        return self._slice(kernel.ST_P, n * n).reshape(n, n)

    @property
    def _updates(self) -> int:
        return int(self._st[self._ic[kernel.ST_UPDATES]])

    @property
    def innovation(self) -> np.ndarray | None:
        """nu = y - h(x_pred, u) of the last update (None before one)."""
        return self._slice(kernel.ST_NU, self.n_outputs) if self._updates else None

    @property
    def innovation_covariance(self) -> np.ndarray | None:
        """S = H P H' + R of the last update (None before one)."""
        p = self.n_outputs
        return self._slice(kernel.ST_S, p * p).reshape(p, p) if self._updates else None

    @property
    def nis(self) -> float:
        """nu' S^-1 nu of the last update (nan before one)."""
        return self.health

    def diagnostics(self):
        updates = self._updates
        mean = float(self._st[self._ic[kernel.ST_NIS_SUM]]) / updates if updates else math.nan
        return {
            "trace(P)": f"{float(np.trace(self.covariance)):.4g}",
            "NIS (last update)": f"{self.nis:.4g}",
            "NIS mean since reset": f"{mean:.4g} over {updates} updates (expected "
                                    f"{self.n_outputs} when the noise settings are right)",
            "prediction": "linearised exact step: one expm of the Van Loan block matrix per "
                          "sub-step (Phi, Qd and the mean)",
            "guarantee": "none (asymptotic, local)",
        }
