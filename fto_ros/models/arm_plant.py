"""The simulated arm's equations of motion and their integration (ROS-free).

Every joint of a :class:`~fto_ros.arm.RigidBodyModel` (the TRUE arm, which may differ from
the URDF a user has) moves: ``M(q) a + C(q, v) v + g(q) + tau_f(v) = tau + J_c(q)^T F_c(t)``,
Pinocchio's articulated-body algorithm. The driven joints (index ``driven``: the arm) get the
torque the controller commands, held over each control interval; the others (a gripper's
fingers) get the force of a stiff finger drive inside the step, critically damped at
``drive_omega`` rad/s around a given trajectory: ``tau_P = K (q_d(t) - q_P) + D (v_d(t) -
v_P)``, K = M_PP(q0) omega^2, D = 2 M_PP(q0) omega (a mimic finger's trajectory is its
parent's through the mimic relation). The fingers' motion acts on the arm through M(q).

Integration: classical RK4, each control interval [t_k, t_k+1] cut at the contacts' switching
and ramp times (no RK4 step straddles a discontinuity of the force or its slope; which
contacts act over a piece is decided at its midpoint, their force follows its ramp inside
it) and each piece integrated in steps of at most ``max_step``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..core.errors import ConfigError, SimulationFailed


@dataclass(frozen=True)
class Contact:
    """A force ``force`` (N, world axes) on link ``link`` from ``t`` for ``duration`` s,
    ramped linearly over ``rise`` s at both ends (0: a step)."""
    link: str
    t: float
    duration: float
    force: tuple[float, float, float]
    rise: float = 0.0

    def scale(self, t: float) -> float:
        """The fraction of the force acting at t, in [0, 1] (on for t in [t, t + duration),
        to 1 ns: the switching times are sums of floats)."""
        a, b = self.t - 1e-9, self.t + self.duration - 1e-9
        if t < a or t >= b:
            return 0.0
        if self.rise <= 0.0:
            return 1.0
        return min(1.0, (t - a) / self.rise, (b - t) / self.rise)

    def ramp(self, t: float) -> float:
        """The force's fraction at t inside an interval where it acts (no switching)."""
        if self.rise <= 0.0:
            return 1.0
        return min(1.0, (t - self.t) / self.rise, (self.t + self.duration - t) / self.rise)

    def breaks(self) -> tuple[float, ...]:
        """The times where the force or its slope jumps."""
        a, b = self.t, self.t + self.duration
        if self.rise <= 0.0:
            return a, b
        r = min(self.rise, 0.5 * self.duration)
        return a, a + r, b - r, b


def check_contacts(model, contacts, q0) -> list[Contact]:
    """The contacts, checked: a finite 3-vector force, duration > 0, rise >= 0, a link of the
    model (ConfigError otherwise)."""
    out = []
    for c in contacts:
        f = np.asarray(c.force, dtype=float)
        if f.shape != (3,) or not np.all(np.isfinite(f)) or not (c.duration > 0) \
                or not (c.rise >= 0) or not math.isfinite(c.t):
            raise ConfigError("contact", f"{c}: needs a finite 3-vector force, duration > 0, "
                                         f"rise >= 0")
        model.jacobian(c.link, q0)                     # ConfigError for an unknown link
        out.append(Contact(c.link, float(c.t), float(c.duration), tuple(float(x) for x in f),
                           float(c.rise)))
    return out


#: a finger trajectory: t -> (q_d, v_d) of the joints that are not driven
Trajectory = Callable[[float], tuple[np.ndarray, np.ndarray]]


class ArmPlant:
    """The true arm's dynamics and its integrator (module doc)."""

    def __init__(self, model, driven, q0_driven, trajectory: Trajectory | None = None,
                 drive_omega: float = 2000.0):
        self.model, self.n = model, model.n
        self.A = np.asarray(driven, dtype=int)
        self.P = np.setdiff1d(np.arange(self.n), self.A)
        if self.P.size and trajectory is None:
            raise ConfigError("joints", "joints that are not driven need a trajectory")
        self.trajectory = trajectory
        self.contacts: list[Contact] = []
        self.kp = self.kd = None
        if self.P.size:
            m = np.diag(model.mass_matrix(self.start(0.0, q0_driven)[0]))[self.P]
            self.kp, self.kd = m * drive_omega ** 2, 2 * m * drive_omega

    def start(self, t: float, qA):
        """(q, v) of every joint at t with the driven joints at qA, at rest, the fingers on
        their trajectory."""
        q, v = np.zeros(self.n), np.zeros(self.n)
        q[self.A] = qA
        if self.P.size:
            q[self.P], v[self.P] = self.trajectory(t)
        return q, v

    def external(self, t: float, q, active=None) -> np.ndarray:
        """The contacts' joint torques J^T F at t, every joint: of the contacts acting at t
        (a sample instant), or of ``active`` at their ramp value (inside a step, which
        no switching time cuts)."""
        tau = np.zeros(self.n)
        for c in (self.contacts if active is None else active):
            s = c.scale(t) if active is None else c.ramp(t)
            if s:
                tau += self.model.jacobian(c.link, q)[:3].T @ (s * np.asarray(c.force))
        return tau

    def contact_force(self, t: float) -> np.ndarray:
        """[active (0/1), fx, fy, fz] of the contacts acting at t."""
        active = [c for c in self.contacts if c.scale(t)]
        if not active:
            return np.zeros(4)
        return np.array([1.0, *sum(c.scale(t) * np.asarray(c.force) for c in active)])

    def accel(self, t: float, q, v, tauA, active) -> np.ndarray:
        """The joints' accelerations at t; tauA: the driven joints' torques, active: the
        contacts acting over the current step."""
        if self.P.size:
            tau = np.empty(self.n)
            tau[self.A] = tauA
            qd, vd = self.trajectory(t)
            tau[self.P] = self.kp * (qd - q[self.P]) + self.kd * (vd - v[self.P])
        else:
            tau = tauA
        if active:
            tau = tau + self.external(t, q, active)
        return self.model.forward_dynamics(q, v, tau)

    def advance(self, t0: float, t1: float, q, v, tauA, max_step: float):
        """(q, v) at t1 from t0 with the driven joints' torque tauA held (module doc)."""
        cuts = [t0]
        for c in self.contacts:
            cuts += [b for b in c.breaks() if t0 + 1e-9 < b < t1 - 1e-9]
        cuts = sorted(cuts) + [t1]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b - a <= 1e-12:
                continue
            steps = max(1, math.ceil((b - a) / max_step - 1e-9))
            hs = (b - a) / steps
            active = [c for c in self.contacts if c.scale(0.5 * (a + b))]
            for i in range(steps):
                q, v = self._rk4(a + i * hs, hs, q, v, tauA, active)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise SimulationFailed(f"the simulation diverged at t = {t1:.4f} s")
        return q, v

    def _rk4(self, ts, hs, q, v, tau, active):
        half = ts + hs / 2
        k1v = self.accel(ts, q, v, tau, active)
        k1q = v
        k2q = v + hs / 2 * k1v
        k2v = self.accel(half, q + hs / 2 * k1q, k2q, tau, active)
        k3q = v + hs / 2 * k2v
        k3v = self.accel(half, q + hs / 2 * k2q, k3q, tau, active)
        k4q = v + hs * k3v
        k4v = self.accel(ts + hs, q + hs * k3q, k4q, tau, active)
        return (q + hs / 6 * (k1q + 2 * k2q + 2 * k3q + k4q),
                v + hs / 6 * (k1v + 2 * k2v + 2 * k3v + k4v))
