"""A simulated arm from its URDF: forward dynamics, a joint controller, an encoder, a
gripper and contacts (ROS-free; ``fto-simulate --urdf`` records it).

- **Plant** (:mod:`.arm_plant`): ``M(q) q'' + C(q, v) v + g(q) + tau_f(v) = tau + J_c(q)^T
  F_c(t)`` of the TRUE arm (``model``; it may differ from the URDF the controller and the
  estimators get, ``nominal``), classical RK4 in steps of at most ``1 / (rate substeps)``
  (default 0.25 ms) with the torque held over each control interval. A gripper's fingers
  (:class:`Gripper`) are joints of the arm driven by a stiff drive along a smooth
  trajectory between 10 % and 90 % of their range, open and close once per
  ``gripper_period`` (0: still, at 10 %); a mimic finger's trajectory is ``multiplier
  q_parent + offset`` (its drive keeps it there within microns); their motion acts on the
  arm through M(q).
- **Sampling instants** (:func:`.arm_stream.sample_instants`): ``t_k = k / rate`` plus a
  jitter uniform in [-jitter, jitter] (k >= 1); the controller runs at t_k, the encoder is
  read at t_k, the torque is held until t_k+1.
- **Encoder** (driven joints): ``q_m = resolution * round((q + n) / resolution)``, n ~
  N(0, noise^2) per joint and sample (default 1e-5 rad, 2^-18 rad); a finger's position is
  reported as it is, a mimic finger's as ``multiplier q_parent + offset`` of the reported
  parent (as ros2_control's mimic joints are).
- **Controller**, at each sample, from the measurement only (as a real one) and the NOMINAL
  model: gravity compensation plus a PD on a smooth trajectory, ``tau = g(q_m) + Kp (q_d -
  q_m) + Kd (v_d - v_f)``, v_f the backward difference of q_m over the nominal period through
  a first-order low-pass (``filter_hz``), Kp = M_ii(q0) omega^2, Kd = 2 zeta omega M_ii(q0),
  clipped to the URDF's effort limits. ``q_d = q0 + A (1 - cos(2 pi t / P)) / 2`` per joint:
  starts at rest, reverses its velocity every P / 2.
- **Contacts** (:class:`.arm_plant.Contact`): a force F (world axes, N) on the origin of a named
  link's frame during [t, t + duration), with an optional linear rise and fall; its joint
  torque J^T F is the ground truth of tau_ext.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import ConfigError
from ..arm.model import RigidBodyModel
from .arm_plant import ArmPlant, Contact, SimulationFailed, check_contacts
from .arm_stream import sample_instants

__all__ = ["ArmRun", "ArmSettings", "Contact", "Gripper", "SimulationFailed", "simulate_arm"]


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
    jitter: float = 0.0            # s: the sampling instants' jitter (uniform, +-)
    gripper_period: float = 0.0    # s: one opening and closing of the fingers (0: still)


@dataclass(frozen=True)
class Gripper:
    """The joints the controller does not drive: ``fingers`` name -> (lower, upper) of the
    finger joints that move on the gripper's trajectory, ``mimic`` name -> (parent,
    multiplier, offset) of the joints that follow a finger."""
    fingers: dict
    mimic: dict = field(default_factory=dict)


@dataclass
class ArmRun:
    """Per sample k (the actual instant t[k]), every joint of ``names`` (columns): true q,
    v, the encoder's q_m, the motor torque commanded at t[k] (held until t[k+1]), the true
    external joint torque, the contact force acting; and the controller's gravity term
    g(q_m) and the true friction tau_f(v) (0 on joints not driven). ``driven``: the columns
    of the driven joints."""
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    q_measured: np.ndarray
    tau: np.ndarray
    tau_ext: np.ndarray
    contact: np.ndarray           # (N, 4): active (0/1), force x, y, z
    names: tuple | None = None
    driven: np.ndarray | None = None
    gravity: np.ndarray | None = None
    friction: np.ndarray | None = None
    # read back from a bag (fto_ros.cli.arm_bag): the header stamps (ns), what the stream's
    # effort carried, the link-side torque tau_J and the sample number k of each row
    stamp_ns: np.ndarray | None = None
    effort: np.ndarray | None = None
    tau_j: np.ndarray | None = None
    index: np.ndarray | None = None


def _per_joint(values, n: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.size == 1:
        arr = np.full(n, arr[0])
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise ConfigError(name, f"needs {n} finite values, got {arr.tolist()}")
    return arr


def _gripper_trajectory(model, gripper: Gripper | None, P: np.ndarray, period: float):
    """t -> (q_d, v_d) of the joints not driven (columns P of the model), and the mimic
    relations [(column, parent column, multiplier, offset)]."""
    if not P.size:
        return None, []
    names = [model.joints[i] for i in P]
    gripper = gripper or Gripper({})
    unknown = [j for j in names if j not in gripper.fingers and j not in gripper.mimic]
    if unknown:
        raise ConfigError("joints", f"joint(s) {', '.join(unknown)} are neither driven nor "
                                    f"gripper fingers")
    lo, span = np.zeros(len(names)), np.zeros(len(names))
    for i, j in enumerate(names):
        if j in gripper.fingers:
            a, b = gripper.fingers[j]
            a, b = (0.0, 0.5) if not (math.isfinite(a) and math.isfinite(b)) else (a, b)
            lo[i], span[i] = a + 0.1 * (b - a), 0.8 * (b - a)
    follow = []
    for i, j in enumerate(names):
        if j in gripper.mimic:
            parent, mult, off = gripper.mimic[j]
            if parent not in gripper.fingers or parent not in names:
                raise ConfigError("joints", f"mimic joint {j} follows {parent}, which is not a "
                                            f"gripper finger")
            follow.append((i, names.index(parent), mult, off))
    w = 2 * math.pi / period if period > 0 else 0.0

    def trajectory(t: float):
        c, s = (math.cos(w * t), math.sin(w * t)) if w else (1.0, 0.0)
        q, v = lo + span * (1 - c) / 2, span * w * s / 2
        for i, p, mult, off in follow:
            q[i], v[i] = mult * q[p] + off, mult * v[p]
        return q, v
    return trajectory, [(P[i], P[p], mult, off) for i, p, mult, off in follow]


def simulate_arm(model: RigidBodyModel, s: ArmSettings, *, driven=None,
                 gripper: Gripper | None = None, nominal: RigidBodyModel | None = None) -> ArmRun:
    """Run the simulation (module doc). ``model``: the true arm, every joint that moves;
    ``driven``: the joints the controller drives (names; default: all); ``gripper``: the
    others; ``nominal``: the controller's model, the same joints (default: ``model``).
    ConfigError for bad settings, SimulationFailed for a run that diverges."""
    nominal = model if nominal is None else nominal
    if tuple(nominal.joints) != tuple(model.joints):
        raise ConfigError("joints", "the nominal and the true model need the same joints")
    names = list(model.joints)
    A = np.arange(model.n) if driven is None else \
        np.array([names.index(j) for j in driven], dtype=int)
    n, nA = model.n, A.size
    q0, amp, period = (_per_joint(x, nA, name) for x, name in
                       ((s.q0, "q0"), (s.amplitude, "amplitude"), (s.period, "period")))
    if np.any(period <= 0):
        raise ConfigError("period", "must be > 0")
    if not (s.rate > 0 and s.duration > 0 and int(s.substeps) >= 1):
        raise ConfigError("duration", "duration, rate and substeps must be > 0")
    if not s.gripper_period >= 0:
        raise ConfigError("gripper_period", f"must be >= 0, got {s.gripper_period!r}")
    h = 1.0 / s.rate
    N = int(round(s.duration * s.rate)) + 1
    t = sample_instants(N, h, s.jitter, s.seed)
    P = np.setdiff1d(np.arange(n), A)
    trajectory, mimic = _gripper_trajectory(model, gripper, P, s.gripper_period)
    max_step = h / int(s.substeps)
    plant = ArmPlant(model, A, q0, trajectory)
    q, v = plant.start(0.0, q0)
    plant.contacts = check_contacts(model, s.contacts, q)
    w = 2 * math.pi / period
    M0 = np.diag(nominal.mass_matrix(q))[A]
    kp, kd = M0 * s.omega ** 2, 2 * s.zeta * s.omega * M0
    alpha = -math.expm1(-2 * math.pi * s.filter_hz * h)
    limit = np.where(nominal.effort_limit > 0, nominal.effort_limit, np.inf)[A]
    rng = np.random.default_rng(s.seed)
    out = {k: np.zeros((N, n)) for k in ("q", "v", "q_m", "tau", "tau_ext", "g", "f")}
    contact = np.zeros((N, 4))
    q_prev_m, v_f = None, np.zeros(nA)
    for k in range(N):
        tk = t[k]
        noisy = q[A] + s.noise * rng.standard_normal(nA)
        q_mA = s.resolution * np.round(noisy / s.resolution) if s.resolution > 0 else noisy
        if q_prev_m is not None:
            v_f += alpha * ((q_mA - q_prev_m) / h - v_f)
        q_prev_m = q_mA
        q_m = q.copy()                 # the fingers as they are, a mimic one from its parent
        q_m[A] = q_mA
        for i, p, mult, off in mimic:
            q_m[i] = mult * q_m[p] + off
        qd = q0 + amp * (1 - np.cos(w * tk)) / 2
        vd = amp * w * np.sin(w * tk) / 2
        g = nominal.gravity(q_m)[A]
        tau = np.clip(g + kp * (qd - q_mA) + kd * (vd - v_f), -limit, limit)
        out["q"][k], out["v"][k], out["q_m"][k] = q, v, q_m
        out["tau"][k, A], out["g"][k, A] = tau, g
        out["f"][k, A] = model.friction(v)[A]
        out["tau_ext"][k] = plant.external(tk, q)
        contact[k] = plant.contact_force(tk)
        if k == N - 1:
            break
        q, v = plant.advance(tk, t[k + 1], q, v, tau, max_step)
    return ArmRun(t, out["q"], out["v"], out["q_m"], out["tau"], out["tau_ext"], contact,
                  tuple(names), A, out["g"], out["f"])
