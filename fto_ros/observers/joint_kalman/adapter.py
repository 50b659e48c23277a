"""The model-free joint velocity baseline: a Kalman filter on an integrator chain per output.

What a user compares every model-based velocity observer with, and the default for joints
whose model is poor: no plant model at all, only the encoder (its noise and resolution) and
a stated bandwidth.  Per measured output, the chain of order r (``order``: 2 white
acceleration, 3 white jerk, 4 white snap) with the process noise intensity whose
steady-state filter has the ``bandwidth`` at the nominal period (design.py has the relation
and the exact step), the measurement variance R = encoder_noise^2 + resolution^2 / 12.
Every sample: the exact step over the ACTUAL interval (closed forms, any h), the
time-varying covariance, the Joseph-form update, the NIS (health; its mean in
/diagnostics).  It is a tracker of ``track`` (a hosm on the same chain acquires for it).
"""
from __future__ import annotations

import math

import numpy as np

from .. import kernel as K
from ..base import ConfigError, KernelObserver, Param, RestartCovariance
from . import design, kernel

P = "joint_kalman."
#: the (re)start covariance of q, q', q'', q''' when none is given (rad^2, (rad/s)^2, ...)
DEFAULT_P0 = (1.0, 1e2, 1e4, 1e6)
_SUFFIX = ("", "_dot", "_ddot", "_dddot")


def per_output(cfg: dict, name: str, p: int) -> np.ndarray:
    """One value for every output, or p values."""
    v = np.asarray(cfg[name], dtype=float)
    if v.size == 1:
        return np.full(p, float(v[0]))
    if v.size != p:
        raise ConfigError(P + name, f"expected 1 value (every output) or {p}, got {v.size}")
    return v


def default_names(p: int, r: int) -> list[str]:
    """q, q_dot, q_ddot (one output), else q0, q0_dot, ..., q1, ..."""
    bases = ["q"] if p == 1 else [f"q{i}" for i in range(p)]
    return [b + _SUFFIX[k] for b in bases for k in range(r)]


class JointKalmanFilter(RestartCovariance, KernelObserver):
    TYPE = "joint_kalman"
    KERNEL = kernel
    DESCRIPTION = ("model-free joint velocity baseline: a Kalman filter on an integrator chain "
                   "per output, noise from the encoder and a stated bandwidth (asymptotic)")
    HEALTH_NAME = "NIS = sum nu^2 / s, the normalised innovation squared of the last update (mean p)"
    PARAMS = (
        Param("n_outputs", "int", 1, "measured outputs p (joint positions), one chain each",
              min=1, max=64),
        Param("order", "int", 3, "states per chain: 2 (white acceleration), 3 (white jerk), "
              "4 (white snap)", min=2, max=4),
        Param("bandwidth", "double_array", None, "Hz, one value or one per output: the -3 dB "
              "frequency of the steady-state filter's position estimate at sample_period "
              "(sets the process noise, docs/joint_kalman.md)", gt=0.0, read_only=False),
        Param("encoder_noise", "double_array", None, "standard deviation of one sample's "
              "noise, in the output's unit (rad), one value or one per output", min=0.0,
              read_only=False),
        Param("resolution", "double_array", [0.0], "the encoder's quantisation step (rad), one "
              "value or one per output; adds resolution^2 / 12 to the variance", min=0.0,
              read_only=False),
        Param("sample_period", "double", 0.001, "nominal sample period (s) at which the "
              "bandwidth holds (every step is discretised exactly at its actual length)",
              gt=0.0, max=10.0, read_only=False),
        Param("initial_covariance", "double_array", [], "the (re)start covariance's diagonal: "
              "order values (every output) or n; empty: 1, 1e2, 1e4, 1e6 in units^2",
              min=0.0, read_only=False),
        Param("initial_state", "string", "measurement", "where a (re)start without an explicit "
              "initial estimate begins: the first measurement (position = y, variance R; "
              "derivatives 0 with the initial covariance) or zero (a correction from 0)",
              choices=("measurement", "zero"), read_only=False),
        Param("state_names", "string_array", [], "names of the n = p order states (empty: q, "
              "q_dot, q_ddot, ...)"),
    )

    def __init__(self, cfg: dict):
        p, r = cfg["n_outputs"], cfg["order"]
        n = p * r
        self.n_states, self.n_outputs, self.n_inputs, self.order = n, p, 0, r
        self.sample_period = h0 = cfg["sample_period"]
        self.bandwidth = per_output(cfg, "bandwidth", p)
        noise = per_output(cfg, "encoder_noise", p)
        res = per_output(cfg, "resolution", p)
        self.variance = np.array([design.measurement_variance(a, b) for a, b in zip(noise, res)])
        if np.any(self.variance <= 0) or not np.all(np.isfinite(self.variance)):
            raise ConfigError(P + "encoder_noise", "encoder_noise and resolution are both 0 for "
                              "an output: the filter needs the measurement's variance")
        self.intensity = np.array([design.process_intensity(r, f, R, h0, P + "bandwidth")
                                   for f, R in zip(self.bandwidth, self.variance)])
        p0 = list(cfg["initial_covariance"]) or list(DEFAULT_P0[:r])
        if len(p0) == r:
            p0 = p0 * p
        if len(p0) != n or min(p0) <= 0 or not all(math.isfinite(v) for v in p0):
            raise ConfigError(P + "initial_covariance", f"expected {r} or {n} positive values, "
                              f"got {cfg['initial_covariance']}")
        self.state_names = list(cfg["state_names"]) or default_names(p, r)
        if len(self.state_names) != n:
            raise ConfigError(P + "state_names", f"expected {n} names, got {len(self.state_names)}")
        offs, size = kernel.layout(p, r)
        c = np.concatenate(([math.inf], self.intensity, self.variance, np.diag(p0).ravel()))
        ints = offs + [K.C_HEADER, K.C_HEADER + p, K.C_HEADER + 2 * p,
                       int(cfg["initial_state"] == "measurement"), 0]
        ic = K.layout_ic(n, K.HEADER, extra_ints=[p, r] + ints)
        self._build_kernel(c, ic, np.zeros(kernel.scratch_size(r)), size)
        self.reset()

    # -- what a tracker provides (observers/track) -------------------------------------------
    @property
    def R(self) -> np.ndarray:
        """The per-sample measurement covariance (p x p, diagonal)."""
        return np.diag(self.variance)

    def _p0(self) -> np.ndarray:
        """The (re)start covariance P0 in the constants (its diagonal blocks per output are
        used)."""
        n, o = self.n_states, K.C_HEADER + 2 * self.n_outputs
        return self._c[o:o + n * n].reshape(n, n)

    # -- outputs ------------------------------------------------------------------------------
    def _slice(self, which: int, size: int) -> np.ndarray:
        o = int(self._ic[which])
        return self._st[o:o + size]

    @property
    def covariance(self) -> np.ndarray:
        """P of the last update, block diagonal (n x n)."""
        p, r = self.n_outputs, self.order
        blocks = self._slice(kernel.ST_P, p * r * r).reshape(p, r, r)
        out = np.zeros((self.n_states, self.n_states))
        for c in range(p):
            out[c * r:(c + 1) * r, c * r:(c + 1) * r] = blocks[c]
        return out

    @property
    def _updates(self) -> int:
        return int(self._st[self._ic[kernel.ST_UPDATES]])

    @property
    def innovation(self) -> np.ndarray | None:
        """nu = y - q_pred of the last update (None before one)."""
        return self._slice(kernel.ST_NU, self.n_outputs).copy() if self._updates else None

    @property
    def nis(self) -> float:
        """nu' S^-1 nu of the last update (nan before one)."""
        return self.health

    @property
    def nis_mean(self) -> float:
        """The mean NIS since the (re)start (p when the noise settings fit the data)."""
        updates = self._updates
        return float(self._st[self._ic[kernel.ST_NIS_SUM]]) / updates if updates else math.nan

    def steady_state_std(self) -> np.ndarray:
        """sqrt of the steady-state posterior variances at the nominal period, per output and
        state (p x r): what the filter expects of its errors on its own model."""
        cached = getattr(self, "_ss_std", None)
        if cached is not None:
            return cached
        out = np.zeros((self.n_outputs, self.order))
        for c in range(self.n_outputs):
            Pp, Kg = design.steady_state(self.order, self.sample_period, self.intensity[c],
                                         self.variance[c])
            L = np.eye(self.order) - np.outer(Kg, np.eye(self.order)[0])
            post = L @ Pp @ L.T + self.variance[c] * np.outer(Kg, Kg)
            out[c] = np.sqrt(np.maximum(np.diag(post), 0.0))
        self._ss_std = out
        return out

    def diagnostics(self):
        updates, mean = self._updates, self.nis_mean
        fmt = lambda v: ", ".join(f"{x:.4g}" for x in np.ravel(v))  # noqa: E731
        return {
            "model": f"integrator chain of order {self.order} per output (white "
                     f"{('acceleration', 'jerk', 'snap')[self.order - 2]}), exact step at every "
                     "actual interval",
            "bandwidth (Hz)": fmt(self.bandwidth),
            "process noise intensity qc": fmt(self.intensity),
            "measurement variance R": fmt(self.variance),
            "steady-state std at the nominal period": fmt(self.steady_state_std()),
            "NIS (last update)": f"{self.nis:.4g}",
            "NIS mean since reset": f"{mean:.4g} over {updates} updates (expected "
                                    f"{self.n_outputs} when the noise settings are right)",
            "guarantee": "none (asymptotic)",
        }
