"""A simulated arm from its URDF: forward dynamics, a joint controller, an encoder and
contacts (ROS-free; ``fto-simulate --urdf`` records it).

- **Plant**: ``M(q) q'' + C(q, v) v + g(q) + tau_f(v) = tau + J_c(q)^T F_c(t)``, Pinocchio's
  articulated-body algorithm, classical RK4 at ``rate * substeps`` (default 4 kHz, 0.25 ms)
  with the torque held over each control period (a drive applies the commanded torque until
  the next command). Contact switching times are rounded to the internal step, so no RK4
  step straddles one.
- **Encoder**: ``q_m = resolution * round((q + n) / resolution)``, n ~ N(0, noise^2) per
  joint and sample (default 1e-5 rad, 2^-18 rad).
- **Controller**, at each sample, from the measurement only (as a real one): gravity
  compensation plus a PD on a smooth trajectory, ``tau = g(q_m) + Kp (q_d - q_m) + Kd (v_d -
  v_f)``, v_f the backward difference of q_m through a first-order low-pass (``filter_hz``),
  Kp = M_ii(q0) omega^2, Kd = 2 zeta omega M_ii(q0), clipped to the URDF's effort limits.
  ``q_d = q0 + A (1 - cos(2 pi t / P)) / 2`` per joint: starts at rest, reverses velocity.
- **Contacts**: a force F (world axes, N) on the origin of a named link's frame during
  [t, t + duration), with an optional linear rise and fall; its joint torque J^T F is the
  ground truth of tau_ext.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..arm.model import RigidBodyModel


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


@dataclass
class ArmSettings:
    """Simulation settings (defaults: the committed arm bags)."""
    duration: float = 10.0
    rate: float = 1000.0
    substeps: int = 4
    noise: float = 1e-5
    resolution: float = 2.0 ** -18
    seed: int = 0
    q0: tuple = (0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0)
    amplitude: tuple = (0.5, 0.3, 0.5, 0.4, 0.6, 0.5, 0.8)
    period: tuple = (4.0, 5.0, 3.5, 4.5, 3.0, 3.3, 2.5)
    omega: float = 25.0
    zeta: float = 0.8
    filter_hz: float = 50.0
    contacts: list = field(default_factory=list)


@dataclass
class ArmRun:
    """Per sample k (time t[k]): true q, v, the encoder's q_m, the torque commanded at t[k]
    (held until t[k+1]), the true external joint torque and the contact force acting."""
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    q_measured: np.ndarray
    tau: np.ndarray
    tau_ext: np.ndarray
    contact: np.ndarray           # (N, 4): active (0/1), force x, y, z


def _per_joint(values, n: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.size == 1:
        arr = np.full(n, arr[0])
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: needs {n} finite values, got {arr.tolist()}")
    return arr


def simulate_arm(model: RigidBodyModel, s: ArmSettings) -> ArmRun:
    """Run the simulation (module doc); ValueError for bad settings or a diverging run."""
    n = model.n
    q0, amp, period = (_per_joint(x, n, name) for x, name in
                       ((s.q0, "q0"), (s.amplitude, "amplitude"), (s.period, "period")))
    if np.any(period <= 0):
        raise ValueError("period: must be > 0")
    if not (s.rate > 0 and s.duration > 0 and int(s.substeps) >= 1):
        raise ValueError("duration, rate and substeps must be > 0")
    h = 1.0 / s.rate
    hs = h / int(s.substeps)
    steps = int(round(s.duration * s.rate))
    contacts = []
    for c in s.contacts:                       # switching times on the internal grid
        f = np.asarray(c.force, dtype=float)
        if f.shape != (3,) or not np.all(np.isfinite(f)) or c.duration <= 0 or c.rise < 0:
            raise ValueError(f"contact {c}: needs a finite 3-vector force, duration > 0, rise >= 0")
        model.jacobian(c.link, q0)             # ConfigError for an unknown link
        contacts.append(Contact(c.link, round(c.t / hs) * hs, round(c.duration / hs) * hs,
                                tuple(f), c.rise))
    w = 2 * math.pi / period
    M0 = np.diag(model.mass_matrix(q0))
    kp, kd = M0 * s.omega ** 2, 2 * s.zeta * s.omega * M0
    alpha = -math.expm1(-2 * math.pi * s.filter_hz * h)
    limit = np.where(model.effort_limit > 0, model.effort_limit, np.inf)
    rng = np.random.default_rng(s.seed)

    def external(t, q):
        tau = np.zeros(n)
        for c in contacts:
            a = c.scale(t)
            if a:
                tau += model.jacobian(c.link, q)[:3].T @ (a * np.asarray(c.force))
        return tau

    def deriv(ts, t, q, v, tau):
        # the contact at a time inside the step [ts, ts + hs]: a switch on its boundary acts
        # on the whole step after it, never on the stages of the one before
        tc = min(max(t, ts + 1e-7 * hs), ts + (1 - 1e-7) * hs)
        return v, model.forward_dynamics(q, v, tau + external(tc, q))

    N = steps + 1
    out = {k: np.zeros((N, n)) for k in ("q", "v", "q_m", "tau", "tau_ext")}
    contact = np.zeros((N, 4))
    q, v = q0.copy(), np.zeros(n)
    q_prev_m, v_f = None, np.zeros(n)
    for k in range(N):
        t = k * h
        q_m = s.resolution * np.round((q + s.noise * rng.standard_normal(n)) / s.resolution) \
            if s.resolution > 0 else q + s.noise * rng.standard_normal(n)
        if q_prev_m is not None:
            v_f += alpha * ((q_m - q_prev_m) / h - v_f)
        q_prev_m = q_m
        qd = q0 + amp * (1 - np.cos(w * t)) / 2
        vd = amp * w * np.sin(w * t) / 2
        tau = np.clip(model.gravity(q_m) + kp * (qd - q_m) + kd * (vd - v_f), -limit, limit)
        out["q"][k], out["v"][k], out["q_m"][k], out["tau"][k] = q, v, q_m, tau
        out["tau_ext"][k] = external(t, q)
        active = [c for c in contacts if c.scale(t)]
        if active:
            contact[k] = [1.0, *sum(c.scale(t) * np.asarray(c.force) for c in active)]
        if k == steps:
            break
        for i in range(int(s.substeps)):       # classical RK4, torque held
            ts = t + i * hs
            k1q, k1v = deriv(ts, ts, q, v, tau)
            k2q, k2v = deriv(ts, ts + hs / 2, q + hs / 2 * k1q, v + hs / 2 * k1v, tau)
            k3q, k3v = deriv(ts, ts + hs / 2, q + hs / 2 * k2q, v + hs / 2 * k2v, tau)
            k4q, k4v = deriv(ts, ts + hs, q + hs * k3q, v + hs * k3v, tau)
            q = q + hs / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v = v + hs / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError(f"the simulation diverged at t = {t + h:.4f} s")
    t = np.arange(N) * h
    return ArmRun(t, out["q"], out["v"], out["q_m"], out["tau"], out["tau_ext"], contact)
