"""The acquire-then-track composition as per-sample Python, for an acquirer whose family is
not yet a compiled kernel (it runs on runner/legacy.py, as that acquirer alone would).

The same rules as the compiled composition (kernel.py; design.py has them in words), one
difference: a re-acquisition whose first acquirer sample is rejected has already advanced
the tracker here (the compiled composition rejects the whole sample).  Remove this module,
and its choice in design.py, once every family in ACQUIRERS is compiled.  ROS-free.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..base import Observer, SampleRejected
from .design import ACQUIRING, REACQUIRING, TRACKING, TrackObserver


class LegacyTrackObserver(TrackObserver):
    """The composition driving its children through their Python protocol."""

    def __init__(self, cfg: dict):
        super().__init__(cfg)
        self.handovers = self.reacquisitions = 0      # over the observer's life (diagnostics)
        self._run_handovers = self._run_reacquisitions = 0   # since the last (re)start
        self._mode = ACQUIRING
        self._nis: deque[float] = deque()
        self._nis_sum = 0.0
        self._quiet = 0
        self._t = math.nan

    # -- protocol --------------------------------------------------------------------------
    def update_checked(self, t, y, u):
        self._t = t                                   # the children keep their own clocks
        super().update_checked(t, y, u)

    @property
    def max_step(self):
        return min(self.acquirer.max_step, self.tracker.max_step)

    def _restart(self, x0_hat):
        self.acquirer.reset(None, x0_hat)
        self.tracker.reset(None)
        self._mode = ACQUIRING
        self._run_handovers = self._run_reacquisitions = 0
        self._clear_window()
        self._quiet = 0

    def _first(self, y, u, gap):
        self.acquirer.update_checked(self._t, y, u)
        self._acquired(y, u)

    def _step(self, s, h, y, u):
        t = self._t
        if self._mode == ACQUIRING:
            self.acquirer.update_checked(t, y, u)     # a rejection leaves both untouched
            self._acquired(y, u)
            return
        self.tracker.update_checked(t, y, u)          # a rejection leaves both untouched
        if self._mode == REACQUIRING:
            try:
                self.acquirer.update_checked(t, y, u)
            except SampleRejected:
                self.acquirer.reset(None)             # acquire afresh from the next sample
                return
            self._acquired(y, u)
            return
        if self._inconsistent(self.tracker.nis):
            self.reacquisitions += 1
            self._run_reacquisitions += 1
            self._mode = REACQUIRING
            self._clear_window()
            self._quiet = 0
            self.acquirer.reset(None)
            self.acquirer.update_checked(t, y, u)

    def _acquired(self, y, u) -> None:
        """Hand over when the acquirer's guarantee (or certificate) holds at this sample."""
        a = self.acquirer
        gt = a.guaranteed_time
        if math.isfinite(gt):
            ready = a.time_since_start >= gt - 1e-9
        else:
            res = a.output_residual
            self._quiet = self._quiet + 1 if math.isfinite(res) and \
                res <= self.certificate_residual else 0
            ready = self._quiet >= self.certificate_samples
        if not ready:
            return
        k = self.tracker
        x0 = np.array(a.estimate, dtype=float)
        k.P0 = self.handover_covariance
        k.reset(None, x0)
        try:
            k.update_checked(self._t, y, u)
        except SampleRejected:
            # the tracker cannot start here: publish the acquirer (past its guarantee) and
            # try again at the next sample
            k.reset(None)
            self._mode = ACQUIRING
            return
        self.handovers += 1
        self._run_handovers += 1
        self._mode = TRACKING
        self._clear_window()

    def _clear_window(self) -> None:
        self._nis.clear()
        self._nis_sum = 0.0

    def _inconsistent(self, nis: float) -> bool:
        """Add the tracker's NIS to the window; whether the window test fails."""
        v = min(nis, self.clip) if math.isfinite(nis) else self.clip
        self._nis.append(v)
        self._nis_sum += v
        if len(self._nis) > self.window:
            self._nis_sum -= self._nis.popleft()
        elif len(self._nis) == self.window:
            self._nis_sum = math.fsum(self._nis)      # once per fill: no drift
        return len(self._nis) == self.window and self._nis_sum > self.threshold

    # -- outputs ---------------------------------------------------------------------------
    @property
    def _published(self) -> Observer:
        return self.acquirer if self._mode == ACQUIRING else self.tracker

    @property
    def estimate(self):
        return self._published.estimate

    @property
    def output_residual(self):
        return self._published.output_residual

    @property
    def guaranteed_time(self):
        return self.acquirer.guaranteed_time

    @property
    def converged(self) -> bool:
        return self._mode == TRACKING

    def convergence_extra(self) -> tuple[float, ...]:
        return float(self._mode), float(self._run_handovers), float(self._run_reacquisitions)

    @property
    def health(self):
        if self._mode != TRACKING or not self._nis:
            return 0.0
        return self._nis_sum / self.threshold

    def _summary(self):
        return (self._mode, self.handovers, self.reacquisitions, self._run_handovers,
                self._run_reacquisitions, self._nis_sum, len(self._nis))
