"""One arm's external torques and collisions, message by message (ROS-free): the code path
of the external-torque node, usable offline on the same messages.

Per JointState (names, positions, efforts, stamp):

- the joints are taken by name with :class:`~fto_ros.runner.intake.JointIntake` (any order;
  a missing or duplicated joint, or a field shorter than ``name``, refuses that joint with
  its reason), then each joint's values are judged (a NaN or infinite position or torque,
  |q| >= 1e3, |tau| >= 1e6): every refused joint is counted per joint and reason, and the
  sample is not used (the estimator needs every joint; nothing is ever mis-assigned);
- the stamp: zero, repeated or backwards (by up to 0.5 s) is rejected; closer than half a
  period is rejected (``stamp_too_close``); any other step that is not the nominal period
  within 0.1 % (a gap, a lost or refused sample) restarts the estimators at this sample
  (restart ``gap``; ``time_jump`` for a jump back of more than 0.5 s): the window estimate is
  back T later;
- the window estimator, the optional momentum observer, then the collision detector on the
  window estimate divided by its noise gain (radians of encoder noise).
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from ..core.reasons import CODE, REJECTIONS
from ..arm.collision import Collision, detection_time
from ..arm.external_torque import SampleRejected
from ..arm.steps import MAX_POSITION, MAX_TORQUE
from .intake import JointIntake
from .torque_settings import TorqueSetup

#: a jump back in time by more than this (s) restarts instead of being rejected
JUMP_BACK = 0.5


@dataclass
class TorqueResult:
    """What one accepted sample gives (None: not yet / not run / nothing fired)."""
    tau_ext: np.ndarray | None
    momentum: np.ndarray | None
    collision: Collision | None
    wrench: np.ndarray | None = None          # (f; m) at wrench.link, world axes


class TorqueLoop:
    """The node's processing of an arm's JointState stream (module doc)."""

    def __init__(self, setup: TorqueSetup):
        self.setup = setup
        self.model, self.est, self.gmo = setup.model, setup.estimator, setup.momentum
        self.detector = setup.detector
        self.joints = list(self.model.joints)
        self.h = self.est.h
        self.link, self.force_only = setup.flat["wrench.link"], setup.flat["wrench.force_only"]
        self.intake = JointIntake(self.joints, ["position"], ["effort"], 1)
        self.accepted = 0
        self.rejected: Counter = Counter()              # reason -> samples
        self.joint_rejected = [Counter() for _ in self.joints]   # per joint: reason -> count
        self.restarts: Counter = Counter()
        self.last_t: float | None = None
        self._base_ns = 0
        self.tau_ext: np.ndarray | None = None
        self.scale: np.ndarray | None = None

    def warm_up(self) -> None:
        """Run the estimators over one window of samples at rest, then restart them: the
        compiled steps are loaded (or compiled) now, not at the first message (a second's
        stall there would overflow a 1 kHz input queue)."""
        zeros = np.zeros(len(self.joints))
        for est in (self.est, self.gmo):
            if est is not None:
                for k in range(self.est.samples + 2):
                    est.update(k * self.h, zeros, zeros)
                est.reset()

    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1

    def _restart(self, reason: str) -> None:
        self.est.reset()
        if self.gmo is not None:
            self.gmo.reset()
        self.restarts[reason] += 1
        self.tau_ext = None

    def _values(self, names, positions, efforts):
        """(q, tau) of the configured joints, or None (counted) when a joint is refused."""
        y, u, refused = self.intake.take(names, {"position": positions, "effort": efforts})
        q, tau = y[:, 0], u[:, 0]
        # NaN fails both comparisons: one test per vector in the common case
        if not refused.any() and np.abs(q).max() < MAX_POSITION \
                and np.abs(tau).max() < MAX_TORQUE:
            return q, tau
        bad_q = ~(np.abs(q) < MAX_POSITION)               # NaN and inf included
        bad_u = ~(np.abs(tau) < MAX_TORQUE)
        ok = refused == 0
        refused[ok & bad_q] = np.where(np.isfinite(q[ok & bad_q]), CODE["measurement_implausible"],
                                       CODE["measurement_non_finite"])
        ok = refused == 0
        refused[ok & bad_u] = np.where(np.isfinite(tau[ok & bad_u]), CODE["input_implausible"],
                                       CODE["input_non_finite"])
        if not refused.any():
            return q, tau
        for j in np.flatnonzero(refused):
            self.joint_rejected[j][REJECTIONS[refused[j]]] += 1
        self._reject(REJECTIONS[int(refused[refused > 0][0])])
        return None

    def _time(self, stamp_ns: int) -> float | None:
        """The sample's time in s since the stream's first stamp (a float of wall-clock
        seconds would keep only 0.2 us), or None when the stamp is rejected (counted)."""
        if stamp_ns <= 0:
            self._reject("zero_stamp" if stamp_ns == 0 else "bad_stamp")
            return None
        if self.last_t is None:
            self._base_ns = stamp_ns
            return 0.0
        t = (stamp_ns - self._base_ns) * 1e-9
        dt = t - self.last_t
        if dt < -JUMP_BACK:
            self._restart("time_jump")
            self._base_ns, t = stamp_ns, 0.0
        elif dt <= 0:
            self._reject("repeated_stamp" if dt == 0 else "stamp_backwards")
            return None
        elif dt < 0.5 * self.h:
            self._reject("stamp_too_close")
            return None
        elif abs(dt - self.h) > 1e-3 * self.h:
            self._restart("gap")
        return t

    def process(self, stamp_ns: int, names, positions, efforts) -> TorqueResult | None:
        """One message (``stamp_ns``: its header stamp in ns); None when the sample is
        rejected (counted)."""
        values = self._values(names, positions, efforts)
        stamp = None if values is None else self._time(int(stamp_ns))
        if stamp is None:
            return None
        q, tau = values
        try:
            tau_ext = self.est.update(stamp, q, tau)
            momentum = None if self.gmo is None else self.gmo.update(stamp, q, tau)
        except SampleRejected:
            # the model's terms are not finite at this sample: both start again from the next
            self._restart("observer_error")
            self._reject("non_finite_model_term")
            return None
        self.accepted += 1
        self.last_t = stamp
        event = wrench = None
        if tau_ext is not None:
            self.tau_ext = tau_ext
            self.scale = self.est.noise_gain()
            event = self.detector.update(stamp, tau_ext, self.scale)
            if self.link:
                wrench = self.model.wrench(self.link, q, tau_ext, self.force_only)
        return TorqueResult(tau_ext, momentum, event, wrench)

    # -- /diagnostics -----------------------------------------------------------------------
    def joint_status(self, contact_size: float, miss: float) -> list[dict]:
        """Per joint: state, threshold and residual (Nm), guaranteed detection time (ms) of a
        step of ``contact_size`` Nm, refusals; values are strings, as diagnostic_msgs has."""
        det, out = self.detector, []
        for i, joint in enumerate(self.joints):
            entry = {"joint": joint}
            if det.sigma is None or self.scale is None:
                entry["state"] = "calibrating" if self.tau_ext is not None else "waiting"
            else:
                sigma = det.sigma[i] * self.scale[i]
                theta = det.z * sigma
                t_d = detection_time(self.est.step_response, contact_size, theta, sigma, miss)
                entry.update(state="contact" if det.in_contact[i] else "armed",
                             threshold_Nm=f"{theta:.6g}",
                             guaranteed_detection_ms=("inf" if math.isinf(t_d)
                                                      else f"{1e3 * t_d:.3g}"))
            if self.tau_ext is not None:
                entry["residual_Nm"] = f"{self.tau_ext[i]:.6g}"
            entry["rejected"] = str(sum(self.joint_rejected[i].values()))
            for reason, count in sorted(self.joint_rejected[i].items()):
                entry[f"rejected.{reason}"] = str(count)
            out.append(entry)
        return out

    def summary(self) -> dict:
        """The node-level counters and the detector's constants, as strings."""
        det = self.detector
        out = {"accepted": str(self.accepted), "rejected": str(sum(self.rejected.values())),
               "window_s": f"{self.est.window:.6g}", "guaranteed_time_s": f"{self.est.window:.6g}",
               "false_alarm_bound_per_hour": f"{det.false_alarms_per_hour:.6g}",
               "threshold_sigmas": f"{det.z:.6g}", "detections": str(len(det.detections)),
               "calibrated": str(det.sigma is not None).lower()}
        out.update({f"rejected.{k}": str(v) for k, v in sorted(self.rejected.items())})
        out.update({f"restarts.{k}": str(v) for k, v in sorted(self.restarts.items())})
        return out
