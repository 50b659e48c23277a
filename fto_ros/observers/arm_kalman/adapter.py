"""``arm_kalman``: the arm's joint velocities by a Kalman filter on its URDF's rigid-body
model: parameters, design, the kernel's arrays (observers/arm_kalman/kernel.py has the
per-sample step; docs/arm.md the model, the tuning and the measured table).  ROS-free.

The commanded torque drives the prediction through M(q)^-1 (the coupling, the pose-dependent
inertia, gravity and the Coriolis terms come from the URDF), and what the model lacks
(friction, model error, contacts) is a per-joint disturbance torque d, a random walk the
filter estimates beside q and v."""
from __future__ import annotations

import math

import numpy as np

from ...arm import detect as DT
from ...core.errors import ConfigError
from .. import kernel as K
from ..arm_base import ArmObserver, rows_block
from ..base import Param
from . import kernel

P = "arm_kalman."
#: the default disturbance rate per joint, in Nm/sqrt(s) per sqrt(kg m^2) of the joint's
#: inertia M_ii at the neutral pose (measured on the Panda-class arm: docs/arm.md)
RATE_PER_ROOT_INERTIA = 2.0


def _per_joint(cfg, name: str, n: int) -> np.ndarray:
    v = np.asarray(cfg[name], dtype=float)
    if v.size == 1:
        return np.full(n, float(v[0]))
    if v.size != n:
        raise ConfigError(P + name, f"expected 1 value (every joint) or {n}, got {v.size}")
    return v


def scalar_filter(m: float, R: float, sd: float, sa: float, h: float, steps: int = 4000):
    """The steady-state gain K (3) and closed-loop matrix of the one-joint filter (inertia m,
    the kernel's F and Q at the step h): what the detector's noise scale is derived from."""
    F = np.array([[1.0, h, h * h / (2 * m)], [0.0, 1.0, h / m], [0.0, 0.0, 1.0]])
    w = sd / m ** 2
    Q = np.array([[w * h ** 5 / 20 + sa * h ** 3 / 3, w * h ** 4 / 8 + sa * h ** 2 / 2,
                   sd / m * h ** 3 / 6],
                  [0.0, w * h ** 3 / 3 + sa * h, sd / m * h ** 2 / 2],
                  [0.0, 0.0, sd * h]])
    Q = np.triu(Q) + np.triu(Q, 1).T
    Pm = np.diag([R, 1.0, 1.0])
    Kg = np.zeros(3)
    for _ in range(steps):
        Pp = F @ Pm @ F.T + Q
        Kg = Pp[:, 0] / (Pp[0, 0] + R)
        Pm = Pp - np.outer(Kg, Pp[0])
    return Kg, (np.eye(3) - np.outer(Kg, [1.0, 0.0, 0.0])) @ F


def noise_responses(M, R, sd, sa, h, steps: int = 3000) -> np.ndarray:
    """(steps, n, n): d_i's response (Nm) to one unit (rad) of encoder noise on joint j at
    sample 0, of the whole filter at the inertia M (its steady state: the kernel's F, Q)."""
    n = M.shape[0]
    W = np.linalg.inv(M)
    N3 = 3 * n
    A = np.zeros((N3, N3))
    A[:n, n:2 * n] = np.eye(n)
    A[n:2 * n, 2 * n:] = W
    F = np.eye(N3) + A * h + A @ A * h * h / 2
    WS, I = W * sd, np.eye(n)
    WSW = WS @ W.T
    Q = np.block([[WSW * h ** 5 / 20 + np.diag(sa) * h ** 3 / 3,
                   WSW * h ** 4 / 8 + np.diag(sa) * h ** 2 / 2, WS * h ** 3 / 6],
                  [WSW * h ** 4 / 8 + np.diag(sa) * h ** 2 / 2,
                   WSW * h ** 3 / 3 + np.diag(sa) * h, WS * h ** 2 / 2],
                  [WS.T * h ** 3 / 6, WS.T * h ** 2 / 2, np.diag(sd) * h]])
    H = np.hstack([I, np.zeros((n, 2 * n))])
    P = np.diag(np.concatenate([R, np.ones(2 * n)]))
    K = np.zeros((N3, n))
    for _ in range(steps):
        Pp = F @ P @ F.T + Q
        K = Pp[:, :n] @ np.linalg.inv(Pp[:n, :n] + np.diag(R))
        P = Pp - K @ Pp[:n, :]
    closed = (np.eye(N3) - K @ H) @ F
    X, out = K.copy(), np.empty((steps, n, n))
    for k in range(steps):
        out[k] = X[2 * n:]
        X = closed @ X
    return out


class ArmKalmanFilter(ArmObserver):
    TYPE = "arm_kalman"
    KERNEL = kernel
    DESCRIPTION = ("an arm's joint velocities by a Kalman filter on its URDF's rigid-body model "
                   "(the commanded torque drives it) with a disturbance torque per joint "
                   "(asymptotic)")
    HEALTH_NAME = "NIS = nu' S^-1 nu, the normalised innovation squared of the last update " \
                  "(mean n)"
    _IC_SDET, _IC_ROWS = kernel.I_SDET, kernel.I_ROWS
    PARAMS = (
        Param("sample_period", "double", 1e-3, "the stream's nominal period (s): a step longer "
              "than 1.5 of it is a gap, predicted in sub-steps of at most 1.5 periods",
              gt=0.0, max=1.0),
        Param("encoder_noise", "double_array", [1e-5], "standard deviation of one position "
              "sample's noise (rad), one value or one per joint", min=0.0),
        Param("resolution", "double_array", [0.0], "the encoder's quantisation step (rad), one "
              "value or one per joint; adds resolution^2 / 12 to the variance", min=0.0),
        Param("disturbance_rate", "double_array", [], "how fast the disturbance torque d "
              "(friction the model lacks, model error, contacts) may change: the standard "
              "deviation of its random walk per sqrt(s) (Nm/sqrt(s)), one value or one per "
              "joint; empty: RATE_PER_ROOT_INERTIA sqrt(M_ii) at the neutral pose "
              "(docs/arm.md, Tuning)", gt=0.0),
        Param("acceleration_noise", "double_array", [0.0], "a white acceleration beside d "
              "(rad/s^2/sqrt(s)), one value or one per joint (0: none)", min=0.0),
        Param("initial_velocity_std", "double", 1.0, "the (re)start's velocity uncertainty "
              "(rad/s): the filter starts at the first position with v = 0", gt=0.0),
        Param("initial_disturbance_std", "double", 10.0, "the (re)start's disturbance "
              "uncertainty (Nm), d = 0", gt=0.0),
        Param("max_step", "double", 0.1, "the longest step predicted across (s); a longer gap "
              "restarts", gt=0.0, max=10.0),
    )

    def __init__(self, cfg: dict):
        self._arm_setup(cfg)
        n, k, h = self.n_joints, self.n_passive, self.period
        noise = _per_joint(cfg, "encoder_noise", n)
        res = _per_joint(cfg, "resolution", n)
        self.variance = noise ** 2 + res ** 2 / 12.0
        if np.any(self.variance <= 0):
            raise ConfigError(P + "encoder_noise", "encoder_noise and resolution are both 0 for "
                              "a joint: the filter needs the measurement's variance")
        diag = np.diag(self.model.mass_matrix(np.zeros(n)))
        self.sd = (_per_joint(cfg, "disturbance_rate", n) if len(cfg["disturbance_rate"]) else
                   RATE_PER_ROOT_INERTIA * np.sqrt(diag)) ** 2
        self.sa = _per_joint(cfg, "acceleration_noise", n) ** 2
        self._max_step = float(cfg["max_step"])
        if self._max_step < h:
            raise ConfigError(P + "max_step", f"must be at least sample_period ({h:g} s), got "
                              f"{self._max_step:g}")
        p0 = np.concatenate([np.full(n, cfg["initial_velocity_std"] ** 2),
                             np.full(n, cfg["initial_disturbance_std"] ** 2)])
        self._p0v = np.concatenate([np.zeros(n), p0])
        M0 = self.model.mass_matrix(np.zeros(n))
        resp = noise_responses(M0, self.variance, self.sd, self.sa, h)
        gn = np.sqrt(np.sum(resp ** 2, axis=(0, 2))) / np.linalg.norm(M0, axis=1)
        corr = 0.0
        for i in range(n):                        # the calibration's effective samples
            r = resp[:, i, i]
            r0 = r @ r
            corr = max(corr, sum((r[:-l] @ r[l:] / r0) ** 2 for l in range(1, r.size - 1)))
        self.noise_gain = gn
        rows, nb = rows_block(self.model)
        det = self._detector_consts(float(corr))
        c_parts = [[self._max_step, self.model.friction_width, h], self.viscous, self.coulomb,
                   self.torque_factor, self.variance, self.sd, self.sa, self._p0v, gn, rows,
                   det]
        offs = np.cumsum([0] + [len(p) for p in c_parts])
        c = np.concatenate([np.asarray(p, dtype=float) for p in c_parts])
        EST = K.HEADER
        UI = EST + 2 * n
        EXTRA = UI + n
        SC = EXTRA + DT.extras_size(n)
        SDET = SC + kernel.offsets(n, k)[-1]
        meaning = {"commanded_no_gravity": kernel.NO_GRAVITY}.get(self.meaning, 0)
        ints = (n, k, nb, meaning, offs[9], *offs[1:9], offs[10], SC, SDET, EST, UI, EXTRA)
        ic = K.layout_ic(2 * n, EST, n, UI, DT.extras_size(n), EXTRA, extra_ints=ints)
        self._step = None
        self._build_kernel(c, ic, np.zeros(1), SDET + DT.state_size(n))
        DT.init(self._st, SDET, c, int(offs[10]), n)
        self.reset()

    @property
    def gap_tolerance(self) -> float:
        return math.nan

    def gap_rule(self) -> dict[str, str]:
        return {"gap rule: steps predicted across up to (s)": f"{self.max_step:.4g}"}

    def _state(self, what: int, size: int) -> np.ndarray:
        n, k = self.n_joints, self.n_passive
        o = self._ic[kernel.I_SC] + kernel.offsets(n, k)[what]
        return self._st[o:o + size]

    @property
    def covariance(self) -> np.ndarray:
        """P of [q, v, d] after the last update (3n x 3n)."""
        N = 3 * self.n_joints
        return self._state(1, N * N).reshape(N, N).copy()

    def step_response(self, elapsed: float) -> float:
        """The fraction of a step of torque d shows ``elapsed`` s later (the one-joint filter
        at joint 1's inertia at the neutral pose; computed once over 1 s, then looked up)."""
        if self._step is None:
            n, h = self.n_joints, self.period
            m = float(self.model.mass_matrix(np.zeros(n))[0, 0])
            Kg, A = scalar_filter(m, self.variance[0], self.sd[0], self.sa[0], h)
            # a torque step on the plant: the filter's input is its position response
            F = np.array([[1.0, h, h * h / (2 * m)], [0.0, 1.0, h / m], [0.0, 0.0, 1.0]])
            truth, x = np.array([0.0, 0.0, 1.0]), np.zeros(3)
            out = [0.0]
            for _ in range(int(round(1.0 / h))):
                truth = F @ truth
                x = A @ x + Kg * truth[0]
                out.append(float(x[2]))
            self._step = np.array(out)
        k = int(max(elapsed, 0.0) / self.period)
        return float(self._step[min(k, self._step.size - 1)])

    def diagnostics(self):
        out = super().diagnostics()
        sc = self._ic[kernel.I_SC]
        out.update({"disturbance rate (Nm/sqrt(s))": ", ".join(f"{math.sqrt(s):.3g}"
                                                             for s in self.sd),
                    "gaps predicted across": str(int(self._st[sc + kernel.BRIDGED])),
                    "guarantee": "none (asymptotic)"})
        return out
