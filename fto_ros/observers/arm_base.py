"""What the families that estimate an arm's external torques share (external_torque,
momentum_observer): the arm from its parameters (arm/params.py), the sample's
layout (y = the joints' positions, u = [their efforts, the passive joints' positions],
x = [q, v], the unknown input tau_ext by joint name), the detector's constants and state
(arm/detect.py), the run-time payload, the collision reset, the diagnostics.  ROS-free.

A family is a :class:`ArmObserver` with ``ARM = True``: the runner runs ONE observer over
the listed ``joints`` (no per-joint split), takes its samples from a JointState through
:meth:`ArmObserver.intake_spec` (runner/arm_intake.py), and the node declares
``ARM_PARAMS`` instead of the plant block's.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from scipy.stats import chi2

from ..arm import detect as DT
from ..arm.collision import detection_time, threshold_sigmas
from ..arm.tree import COL
from ..core.errors import ConfigError, UsageError
from ..arm import params as AP
from .base import KernelObserver

#: the miss probability of the calibration's upper confidence bound on the residual's level
CONFIDENCE = 1e-3


class ArmObserver(KernelObserver):
    """The arm families' common adapter (module doc); a subclass sets ``PARAMS`` (its own,
    with ``sample_period``), designs its kernel and calls :meth:`_arm_setup` first."""

    ARM = True
    ARM_PARAMS = AP.ARM_PARAMS
    HEALTH_NAME = "largest |tau_ext_i| / its lower (contact) level"

    # -- the arm -----------------------------------------------------------------------
    def _arm_setup(self, cfg: Mapping[str, Any]) -> None:
        a = cfg["arm"]
        self.arm = dict(a)
        self.model = model = AP.build_model(a, cfg.get("joints") or [])
        self.joints = list(model.joints)
        self.passive_joints = list(model.passive_joints)
        self.notes = list(model.robot.notes)
        n, k = model.n, len(self.passive_joints)
        self.n_joints, self.n_passive = n, k
        self.n_states, self.n_outputs, self.n_inputs = 2 * n, n, n + k
        self.state_names = self.joints + [f"{j}_dot" for j in self.joints]
        self.unknown_input_names = list(self.joints)
        #: the extras on ~/convergence (arm/detect.py's): per joint contact and collision
        #: (0/1) and the lower and upper levels (Nm; 0 while unknown)
        self.CONVERGENCE_EXTRA = ("tau_ext_valid", "calibrated", "model_mismatch") + tuple(
            f"{what}.{j}" for what in ("contact", "collision", "lower_Nm", "upper_Nm")
            for j in self.joints)
        self.meaning = a["effort.meaning"]
        self.torque_factor = AP.torque_factors(a, n)
        measured = self.meaning == "measured"          # friction acts motor-side
        self.viscous = np.zeros(n) if measured else model.viscous.copy()
        self.coulomb = np.zeros(n) if measured else model.coulomb.copy()
        self.period = float(cfg["sample_period"])
        self.rate = 1.0 / self.period
        self.row_bound = AP.row_norm_bound(model)

    def intake_spec(self) -> tuple[list[str], list[str], np.ndarray]:
        """(joints, passive joints, the passive joints' start positions): what the runner's
        JointState intake reads (runner/arm_intake.py)."""
        return self.joints, self.passive_joints, self.model.passive_default.copy()

    def _rows(self) -> np.ndarray:
        return self.model.tree.rows.ravel()

    # -- the detector ------------------------------------------------------------------------
    def _detector_consts(self, correlation_sum: float) -> np.ndarray:
        """arm/detect.py's constants; ``correlation_sum``: sum over lags >= 1 of the squared
        autocorrelation of the family's residual (the calibration's effective samples)."""
        a, n = self.arm, self.n_joints
        self.z = threshold_sigmas(a["collision.false_alarms_per_hour"], self.rate, n)
        cal = max(8, int(round(a["collision.calibration"] * self.rate)))
        nu = cal / (1.0 + 2.0 * correlation_sum)
        self.confidence_factor = math.sqrt(nu / chi2.ppf(CONFIDENCE, nu))
        self.calibration_samples = cal
        head = [self.z, self.confidence_factor, cal, a["collision.release"], a["collision.hold"],
                a["collision.upper_factor"], a["collision.mismatch_factor"]]
        return np.concatenate([head, AP.sigmas(a, n), AP.upper_levels(a, n)])

    def _det(self, array: int) -> np.ndarray:
        n = self.n_joints
        o = self._ic[self._IC_SDET] + DT.S_HEAD + array * n
        return self._st[o:o + n]

    def _det_scalar(self, which: int) -> float:
        return float(self._st[self._ic[self._IC_SDET] + which])

    def reset_collision(self) -> int:
        """Clear every latched collision (the node's ~/reset_collision); how many were set."""
        col = self._det(DT.COLLISION)
        count = int(np.count_nonzero(col))
        col[:] = 0.0
        o, n = self._ic[self._K.EXTRA] + DT.X_HEAD + self.n_joints, self.n_joints
        self._st[o:o + n] = 0.0
        return count

    @property
    def calibrated(self) -> bool:
        return self._det_scalar(DT.CALIBRATED) > 0.0

    def mismatch(self) -> list[tuple[str, float]]:
        """(joint, the residual's level over the encoder's noise) of every joint above
        collision.mismatch_factor, once calibrated."""
        if not self.calibrated:
            return []
        level, enc = self._det(DT.LEVEL), self._det(DT.ENC)
        limit = self.arm["collision.mismatch_factor"]
        out = []
        for j, lv, e in zip(self.joints, level, enc):
            f = lv / e if e > 0 else math.inf
            if f > limit:
                out.append((j, float(f)))
        return out

    def mismatch_message(self) -> str | None:
        """'model mismatch: joint X residual 120x the encoder noise; ...' or None."""
        bad = self.mismatch()
        if not bad:
            return None
        return "model mismatch: " + "; ".join(f"joint {j} residual {f:.3g}x the encoder noise"
                                              for j, f in bad) + \
            " (identify the model: fto-identify, docs/external_torque.md)"

    def warnings(self) -> list[str]:
        """What /diagnostics reports as WARN: a model mismatch."""
        bad = self.mismatch_message()
        return [bad] if bad else []

    # -- the payload -------------------------------------------------------------------------
    def set_payload(self, values: Mapping[str, Any]) -> None:
        """New payload.* values (typed) taken at once: the tree's rows in the kernel's
        constants change in place and the family refreshes what its state holds of the old
        model; ConfigError (nothing changed) for a bad value."""
        a = dict(self.arm)
        a.update({k: values[k] for k in AP.PAYLOAD_NAMES if k in values})
        old = self.model.tree.rows.copy()
        try:
            AP.set_payload(self.model, a)
        except ConfigError:
            self.model.tree.rows[:] = old
            raise
        self.arm = a
        o, size = self._ic[self._IC_ROWS], self.model.tree.rows.size
        self._c[o:o + size] = self._rows()
        self._refresh()

    def _refresh(self) -> None:
        """The family's state after a change of the model (default: nothing to do)."""

    # -- diagnostics -------------------------------------------------------------------------
    def gap_rule(self) -> dict[str, str]:
        """The gap rule's figures for /diagnostics (the family's kernel peak gain)."""
        return {"gap rule: steps bridged up to (s)": f"{self.max_step:.4g}",
                "gap rule: tolerance (Nm)": f"{self.gap_tolerance:.4g}"}

    def joint_diagnostics(self) -> list[dict[str, str]]:
        """Per joint: state, levels (Nm, at the last sample), the calibrated level over the
        encoder's noise, the guaranteed detection time of collision.contact_size."""
        n = self.n_joints
        ex = self._ic[self._K.EXTRA]
        contact = self._st[ex + DT.X_HEAD:ex + DT.X_HEAD + n]
        collision = self._st[ex + DT.X_HEAD + n:ex + DT.X_HEAD + 2 * n]
        lower = self._st[ex + DT.X_HEAD + 2 * n:ex + DT.X_HEAD + 3 * n]
        upper = self._st[ex + DT.X_HEAD + 3 * n:ex + DT.X_HEAD + 4 * n]
        level, enc, sigma = self._det(DT.LEVEL), self._det(DT.ENC), self._det(DT.SIGMA)
        tau = self.unknown_input
        out = []
        size, miss = self.arm["collision.contact_size"], self.arm["collision.miss"]
        for i, j in enumerate(self.joints):
            e = {"joint": j, "state": ("collision" if collision[i] else "contact" if contact[i]
                                       else "armed" if lower[i] > 0 else "calibrating")}
            if lower[i] > 0:
                e["lower level (Nm)"] = f"{lower[i]:.4g}"
                e["upper level (Nm)"] = f"{upper[i]:.4g}"
                t_d = self._detection_time(size, lower[i], lower[i] / self.z, miss)
                e["guaranteed detection of %g Nm (ms)" % size] = \
                    "inf" if math.isinf(t_d) else f"{1e3 * t_d:.3g}"
            e["tau_ext (Nm)"] = f"{tau[i]:.4g}"
            if self.calibrated:
                e["residual level (rad)"] = f"{level[i]:.3g}"
                e["encoder noise (rad)"] = f"{enc[i]:.3g}"
                e["residual / encoder noise"] = f"{level[i] / enc[i]:.3g}" if enc[i] > 0 else "inf"
                e["sigma (rad)"] = f"{sigma[i]:.3g}"
            out.append(e)
        return out

    def _detection_time(self, size: float, threshold: float, sigma: float, miss: float) -> float:
        return detection_time(self.step_response, size, threshold, sigma, miss)

    @property
    def max_step(self) -> float:
        """The longest step the family bridges (s): its gap rule's, set as ``_max_step``."""
        return self._max_step

    def step_response(self, elapsed: float) -> float:
        """Fraction of a step of tau_ext shown ``elapsed`` s after it (the family's)."""
        raise UsageError(f"{type(self).__name__} does not define step_response")

    def diagnostics(self) -> dict[str, Any]:
        out = {"joints": ", ".join(self.joints),
               "passive joints": ", ".join(self.passive_joints) or "none",
               "effort meaning": self.meaning,
               "threshold (sigmas)": f"{self.z:.4g}",
               "false-alarm bound (per hour)": f"{self.arm['collision.false_alarms_per_hour']:g}",
               "calibrated": str(self.calibrated).lower(),
               "contact onsets": str(int(self._det_scalar(DT.ONSETS)))}
        out.update(self.gap_rule())
        bad = self.mismatch_message()
        if bad:
            out["model mismatch"] = bad
        for note in self.notes:
            out.setdefault("note", note)
        return out


def rows_block(model) -> tuple[np.ndarray, int]:
    """The tree's packed rows (flat) and their count, for a kernel's constants."""
    rows = np.ascontiguousarray(model.tree.rows, dtype=float)
    assert rows.shape[1] == COL
    return rows.ravel(), rows.shape[0]
