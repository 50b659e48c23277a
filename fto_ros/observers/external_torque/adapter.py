"""The windowed momentum estimator of an arm's external torques: parameters, design, the
kernel's arrays (observers/external_torque/kernel.py has the per-sample step;
docs/external_torque.md the derivation).  ROS-free."""
from __future__ import annotations


import numpy as np

from ...arm import detect as DT
from ...arm.window import weights
from ...core.differentiator import Differentiator
from ...core.errors import ConfigError
from .. import kernel as K
from ..arm_base import ArmObserver, rows_block
from ..base import Param
from . import kernel

P = "external_torque."
#: half-width (samples) of the centred velocity of the velocity-dependent terms
CENTRAL = 4
#: most memory the ring may take (M and Mdot of every sample of the window): with the
#: URDF's joint cap and T = 60 ms at 1 kHz, configuring stays within about 200 MB
MAX_WINDOW_BYTES = 64 * 2 ** 20
#: kappa's peak, 30 (1/2)^2 (1/2)^2: the kernel's largest weight is PEAK / T
PEAK = 1.875


class ExternalTorqueObserver(ArmObserver):
    TYPE = "external_torque"
    KERNEL = kernel
    DESCRIPTION = ("an arm's external joint torques by the windowed momentum identity: exact T "
                   "after any change, on the actual stamps; contact and collision per joint")
    _IC_SDET, _IC_ROWS = kernel.I_SDET, kernel.I_ROWS
    PARAMS = (
        Param("sample_period", "double", 1e-3, "the stream's nominal period (s): the window "
              "holds window / sample_period + 1 samples, and a step longer than it by more "
              "than half is a gap (bridged by the gap rule)", gt=0.0, max=1.0),
        Param("window", "double", 0.06, "T (s): the kernel's length; the estimate is exact T "
              "after any change of tau_ext (at least 8 sample periods)", gt=0.0, max=60.0),
        Param("velocity_L", "double", 300.0, "the velocity differentiator's bound L on the "
              "positions' third derivative (rad/s^3); the gap rule's bound uses it too",
              gt=0.0),
        Param("gap_tolerance", "double", 0.25, "the most a bridged gap may add to tau_ext "
              "(Nm): a step G is bridged while 1/2 (1.875 / T) ||M_i,:||_1 L (G - period)^2 "
              "stays below it on every joint; a longer one restarts", gt=0.0),
    )

    def __init__(self, cfg: dict):
        self._arm_setup(cfg)
        model, n, k = self.model, self.n_joints, self.n_passive
        h, T = self.period, cfg["window"]
        W = round(T / h)
        if not (8 <= W <= 20000 and abs(W * h - T) < 1e-9 + 1e-6 * T):
            raise ConfigError(P + "window", f"must be a whole number of sample periods "
                              f"({h:g} s), at least 8, got {T!r} s")
        slot = kernel.slot_offsets(n, k)[-1]
        ring = 8 * (W + 1) * slot
        if ring > MAX_WINDOW_BYTES:
            raise ConfigError(P + "window", f"{W} samples of {n} joints need "
                              f"{ring / 2 ** 20:.0f} MiB, more than the "
                              f"{MAX_WINDOW_BYTES // 2 ** 20} MiB accepted: a shorter window "
                              f"or fewer joints")
        self.samples, self.window = W, W * h
        self.L = cfg["velocity_L"]
        self.gap_tolerance = cfg["gap_tolerance"]
        self.kernel_peak = PEAK / self.window
        from ...arm.params import gap_step
        step = gap_step(self.gap_tolerance, self.kernel_peak, self.row_bound, self.L, h)
        self._max_step = min(step, 0.5 * self.window)
        self.red = Differentiator(2, self.L, channels=n)
        self._build(W, slot)

    def _correlation_sum(self, W: int) -> float:
        """Sum over lags >= 1 of the squared autocorrelation of the window's noise (its
        momentum weights A on the uniform grid, white encoder noise)."""
        u = np.arange(W + 1) * self.period
        A, B, C, D = np.zeros(W + 1), np.zeros(W + 1), np.zeros(W + 1), np.zeros(W)
        self.noise_gain_nominal = weights(u, W, A, B, C, D)
        r0 = A @ A
        return float(sum((A[:-l] @ A[l:] / r0) ** 2 for l in range(1, W + 1)))

    def _build(self, W: int, slot: int) -> None:
        n, k, m = self.n_joints, self.n_passive, CENTRAL
        rows, nb = rows_block(self.model)
        det = self._detector_consts(self._correlation_sum(W))
        c_parts = [[self._max_step, self.model.friction_width, self.period], self.viscous,
                   self.coulomb, self.torque_factor, rows, self.red.consts, det]
        offs = np.cumsum([0] + [len(p) for p in c_parts])
        c = np.concatenate([np.asarray(p, dtype=float) for p in c_parts])
        EST = K.HEADER
        UI = EST + 2 * n
        EXTRA = UI + n
        SC = EXTRA + DT.extras_size(n)
        SRED = SC + kernel.N_SCALARS
        RING = SRED + self.red.state_size
        SDET = RING + (W + 1) * slot
        size = SDET + DT.state_size(n)
        w_sizes = [self.red.scratch_size, W + 1, W + 1, W + 1, W + 1, W, 2 * m + 1,
                   (2 * m + 1) * n, n, n, 5, 5 * n, n]
        w = np.cumsum([0] + w_sizes)
        ints = (n, k, nb, W, m, kernel.MEANINGS_CODE[self.meaning], offs[4], offs[1], offs[2],
                offs[3], offs[5], offs[6], SC, SRED, RING, SDET, slot, *w[:13], EST, UI, EXTRA)
        ic = K.layout_ic(2 * n, EST, n, UI, DT.extras_size(n), EXTRA, extra_ints=ints)
        self._build_kernel(c, ic, np.zeros(int(w[-1])), size)
        DT.init(self._st, SDET, c, int(offs[6]), n)
        self.reset()

    @property
    def guaranteed_time(self) -> float:
        return float(self._st[K.GUARANTEED])

    def step_response(self, elapsed: float) -> float:
        s = min(max(elapsed / self.window, 0.0), 1.0)
        return float(s ** 3 * (10 - 15 * s + 6 * s * s))

    def _refresh(self) -> None:
        if kernel.refresh(self._st, self._c, self._ic) != 0:
            self.reset()

    def noise_gain(self) -> float:
        """||A|| of the last estimate (rad^-1 s^-2 ...: tau_ext noise per rad of encoder
        noise per unit of ||M_i,:||)."""
        return float(self._st[self._ic[kernel.I_SC] + kernel.GAIN])

    def bridged(self) -> tuple[int, float]:
        """(gaps bridged since the start, the longest step bridged, s)."""
        sc = self._ic[kernel.I_SC]
        return int(self._st[sc + kernel.BRIDGED]), float(self._st[sc + kernel.MAX_BRIDGED])

    def diagnostics(self):
        out = super().diagnostics()
        count, longest = self.bridged()
        out.update({"window T (s)": f"{self.window:.6g}", "window samples": str(self.samples + 1),
                    "gaps bridged": str(count),
                    "longest step bridged (s)": f"{longest:.4g}" if count else "none",
                    "guarantee": f"exact {self.window:g} s after a restart and after any change "
                                 f"of tau_ext (up to the encoder noise)"})
        if count:
            from ...arm.params import gap_bound
            bound = gap_bound(longest, self.kernel_peak, self.row_bound, self.L, self.period)
            out["bound on what that gap added (Nm, worst joint)"] = f"{bound.max():.3g}"
        return out
