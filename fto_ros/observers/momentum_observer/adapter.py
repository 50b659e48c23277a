"""The generalized-momentum observer of an arm's external torques (the baseline):
parameters, design, the kernel's arrays (observers/momentum_observer/kernel.py).  ROS-free."""
from __future__ import annotations

import math

import numpy as np

from ...arm import detect as DT
from .. import kernel as K
from ..arm_base import ArmObserver, rows_block
from ...arm.params import gap_step
from ..base import Param
from . import kernel


def noise_response(gain: float, h: float) -> np.ndarray:
    """r / (K ||M||) for one unit of encoder noise at sample 0 (backward-difference
    velocity, the observer's recursion): its norm is the residual's noise gain, its
    autocorrelation the calibration's."""
    steps = int(min(200000, 40.0 / (gain * h) + 10))
    e = np.zeros(steps)
    e[0] = 1.0
    P = np.diff(np.concatenate(([0.0], e))) / h
    r = np.zeros(steps)
    integral = 0.0
    for k in range(steps):
        if k:
            integral += h * r[k - 1]
        r[k] = gain * (P[k] - integral)
    return r / gain


class MomentumObserverFamily(ArmObserver):
    TYPE = "momentum_observer"
    KERNEL = kernel
    DESCRIPTION = ("the generalized-momentum observer of an arm's external joint torques "
                   "(baseline): a first-order filter of tau_ext, no guaranteed time")
    _IC_SDET, _IC_ROWS = kernel.I_SDET, kernel.I_ROWS
    PARAMS = (
        Param("sample_period", "double", 1e-3, "the stream's nominal period (s): a step longer "
              "than it by more than half is a gap (bridged by the gap rule)", gt=0.0, max=1.0),
        Param("gain", "double", 50.0, "K_O (1/s): r' = K_O (tau_ext - r)", gt=0.0, max=1e5),
        Param("velocity_L", "double", 300.0, "the bound L on the positions' third derivative "
              "(rad/s^3) the gap rule assumes", gt=0.0),
        Param("gap_tolerance", "double", 0.25, "the most a bridged gap may add to the residual "
              "(Nm): a step G is bridged while 1/2 K_O ||M_i,:||_1 L (G - period)^2 stays "
              "below it on every joint; a longer one restarts", gt=0.0),
    )

    def __init__(self, cfg: dict):
        self._arm_setup(cfg)
        n, k, h = self.n_joints, self.n_passive, self.period
        self.gain = float(cfg["gain"])
        self.L, self.gap_tolerance = cfg["velocity_L"], cfg["gap_tolerance"]
        self.kernel_peak = self.gain
        self._max_step = min(gap_step(self.gap_tolerance, self.gain, self.row_bound, self.L, h),
                             5.0 / self.gain)
        resp = noise_response(self.gain, h)
        self.noise = float(np.linalg.norm(resp))
        r0 = resp @ resp
        lags = min(resp.size - 1, 4000)
        corr = sum((resp[:-l] @ resp[l:] / r0) ** 2 for l in range(1, lags))
        rows, nb = rows_block(self.model)
        det = self._detector_consts(float(corr))
        c_parts = [[0.0, self.model.friction_width, h, self.noise], self.viscous, self.coulomb,
                   self.torque_factor, np.full(n, self.gain), rows, det]
        offs = np.cumsum([0] + [len(p) for p in c_parts])
        c = np.concatenate([np.asarray(p, dtype=float) for p in c_parts])
        c[0] = self._max_step
        EST = K.HEADER
        UI = EST + 2 * n
        EXTRA = UI + n
        SC = EXTRA + DT.extras_size(n)
        SDET = SC + kernel.offsets(n, k)[-1]
        meaning = {"commanded_no_gravity": kernel.NO_GRAVITY}.get(self.meaning, 0)
        ints = (n, k, nb, meaning, offs[5], offs[1], offs[2], offs[3], offs[4], offs[6], SC,
                SDET, 0, n, 2 * n, EST, UI, EXTRA)
        ic = K.layout_ic(2 * n, EST, n, UI, DT.extras_size(n), EXTRA, extra_ints=ints)
        self._build_kernel(c, ic, np.zeros(3 * n), SDET + DT.state_size(n))
        DT.init(self._st, SDET, c, int(offs[6]), n)
        self.reset()

    def step_response(self, elapsed: float) -> float:
        return float(1.0 - math.exp(-self.gain * max(elapsed, 0.0)))

    def _refresh(self) -> None:
        if kernel.refresh(self._st, self._c, self._ic) != 0:
            self.reset()

    def diagnostics(self):
        out = super().diagnostics()
        sc = self._ic[kernel.I_SC]
        out.update({"gain K_O (1/s)": f"{self.gain:g}",
                    "gaps bridged": str(int(self._st[sc + kernel.BRIDGED])),
                    "guarantee": "none (a first-order filter of tau_ext)"})
        return out
