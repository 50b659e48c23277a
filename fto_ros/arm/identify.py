"""Friction and inertial corrections of an arm identified from a contact-free recording
(ROS-free; ``fto-identify``, docs/identify.md).

The momentum identity in its window form (:mod:`.identify_windows`) is linear in the
unknowns: per joint the viscous b and Coulomb f_c friction, and the inertial corrections the
data can see, in one of three forms (``Spec.inertia``):

- ``base``: the bodies' inertia parameters in their base combinations (:mod:`.identify_base`;
  the corrections are written per body as ``plant.inertia_delta``);
- ``scale``: one factor per link on its mass, first moment and inertia
  (``plant.inertia_scale``), optionally with a payload at a frame (``payload.*``);
- ``none``: friction only (or, with ``Spec.payload_only``, the payload only: a short stretch
  after a grasp, everything else fixed).

The model handed in is the prior (its URDF, friction and corrections as the params give
them); the fit (:mod:`.identify_fit`) corrects it, refuses what the data cannot see (left at
the prior) and reports residuals against the encoder noise's share.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import ConfigError, short
from .identify_base import PARAMETERS, moving_bodies, structural_base
from .identify_fit import FitRefused, LeastSquares, solve
from .identify_regressor import WindowRegressor
from .model import RigidBodyModel
from .tree import ACTIVE, shift_params
from .urdf import check_inertia

EFFORT_MEANINGS = ("commanded", "commanded_no_gravity", "measured", "current")
INERTIA_FORMS = ("base", "scale", "none")

__all__ = ["EFFORT_MEANINGS", "FitRefused", "Identified", "Spec", "Unknown", "encoder_noise",
           "identify", "torque_from_effort"]


@dataclass(frozen=True)
class Unknown:
    """One parameter of the fit: ``kind`` viscous | coulomb | scale | body | payload."""
    name: str
    kind: str
    prior: float
    joint: int = -1
    link: str = ""
    body: int = -1
    index: int = -1


@dataclass
class Spec:
    """What to fit and how (module doc). ``window`` T (s), one window every ``stride``
    samples, none over a step longer than ``max_gap`` s; ``ratio``: refuse an unknown whose
    standard error exceeds this fraction of its value; ``outlier``: windows beyond this many
    robust standard deviations are contacts (0: keep all); ``encoder_noise`` (rad, per
    joint or one value; None: estimated from the positions)."""
    window: float = 0.1
    stride: int = 10
    max_gap: float = 0.01
    friction: bool = True
    inertia: str = "base"
    links: tuple = ()
    payload: str = ""
    payload_only: bool = False
    ratio: float = 0.5
    outlier: float = 30.0
    encoder_noise: object = None
    velocity_half: int = 6
    effort: str = "commanded"
    torque_constant: object = None
    gear_ratio: object = None


@dataclass
class Identified:
    """The outcome: per unknown its prior, fitted value (the prior where refused) and
    standard error; per joint the residual RMS before and after and the encoder noise's
    share (Nm); the fit's details."""
    model: RigidBodyModel
    spec: Spec
    unknowns: list
    value: np.ndarray
    se: np.ndarray
    fit: LeastSquares
    prior_rms: np.ndarray
    residual_rms: np.ndarray
    noise_rms: np.ndarray
    encoder_noise: np.ndarray
    windows: int
    window_times: np.ndarray | None = None     # the windows' ends (the stamps' time)
    notes: list = field(default_factory=list)
    payload_fitted: tuple | None = None        # (mass, com, inertia about the com)

    @property
    def refused(self) -> list:
        """(unknown, standard error, size) of every unknown left at its prior."""
        return [(self.unknowns[i], se, size) for i, se, size in self.fit.refused]

    def payload(self):
        """(frame, mass, com, inertia 3 x 3 about the com) fitted, or None."""
        if self.payload_fitted is None:
            return None
        return (self.spec.payload, *self.payload_fitted)

    def parameters(self) -> dict:
        """The ROS parameters to write (flat names, ARM_DESIGN's), from the fitted values."""
        out: dict = {}
        kinds = {u.kind for u in self.unknowns}
        m = self.model
        if {"viscous", "coulomb"} & kinds:
            b, fc = m.viscous.copy(), m.coulomb.copy()
            for u, x in zip(self.unknowns, self.value):
                if u.kind == "viscous":
                    b[u.joint] = x
                elif u.kind == "coulomb":
                    fc[u.joint] = x
            out["plant.viscous_friction"] = np.maximum(b, 0.0).tolist()
            out["plant.coulomb_friction"] = np.maximum(fc, 0.0).tolist()
            out["plant.friction_width"] = m.friction_width
        scale = dict(m.tree.inertia_scale)
        delta = {k: v.copy() for k, v in m.tree.inertia_delta.items()}
        for u, x in zip(self.unknowns, self.value):
            if u.kind == "scale" and x != u.prior:
                scale[u.link] = float(x)
            elif u.kind == "body" and x != u.prior:
                delta.setdefault(u.link, np.zeros(10))[u.index] += x - u.prior
        if "scale" in kinds or scale:
            out["plant.inertia_scale.links"] = list(scale)
            out["plant.inertia_scale.factors"] = [scale[k] for k in scale]
        if "body" in kinds or delta:
            out["plant.inertia_delta.links"] = list(delta)
            out["plant.inertia_delta.values"] = [float(x) for k in delta for x in delta[k]]
        got = self.payload()
        if got is not None:
            frame, mass, com, I = got
            out["payload.frame"] = frame
            out["payload.mass"] = float(mass)
            out["payload.com"] = [float(x) for x in com]
            out["payload.inertia"] = [float(I[0, 0]), float(I[0, 1]), float(I[0, 2]),
                                      float(I[1, 1]), float(I[1, 2]), float(I[2, 2])]
        return out


def _payload_from(theta):
    """(mass, com, inertia about the com) of 10 parameters about a frame's origin."""
    mass = float(theta[0])
    com = np.asarray(theta[1:4]) / mass if mass > 0 else np.zeros(3)
    xx, yy, zz, yz, xz, xy = theta[4:10]
    I_o = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return mass, com, I_o - mass * (com @ com * np.eye(3) - np.outer(com, com))


def encoder_noise(t, q, half: int = 4) -> np.ndarray:
    """Per joint, the encoder noise's standard deviation estimated from the positions: each
    sample against the cubic least-squares fit of its 2 half + 1 neighbours over their
    stamps, divided by sqrt(1 - leverage), robust spread (1.4826 x the median absolute)."""
    t, q = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
    N = t.size
    if N < 2 * half + 1:
        raise FitRefused(f"{N} samples: too few to see the encoder noise")
    idx = np.arange(half, N - half)[:, None] + np.arange(-half, half + 1)[None, :]
    dt = t[idx] - t[idx[:, half]][:, None]
    dt /= np.maximum(np.abs(dt).max(axis=1, keepdims=True), 1e-300)
    V = dt[:, :, None] ** np.arange(4)[None, None, :]
    H = (V @ np.linalg.pinv(V))[:, half, :]          # the fit's value at the middle sample
    e = q[half:N - half] - np.einsum("kj,kjn->kn", H, q[idx])
    e /= np.sqrt(np.maximum(1.0 - H[:, half], 1e-12))[:, None]
    return 1.4826 * np.median(np.abs(e - np.median(e, axis=0)), axis=0)


def torque_from_effort(meaning: str, effort, gravity=None, torque_constant=None,
                       gear_ratio=None) -> np.ndarray:
    """The torque acting from each sample to the next, from JointState.effort read as
    ``meaning`` (``effort.meaning``): commanded as it is; commanded_no_gravity plus the
    prior model's g(q) at the sample (the robot adds its own gravity model; the URDF's is the
    best known); measured (link-side tau_J) as it is; current times ``effort.torque_constant``
    and ``effort.gear_ratio`` (per joint or one value)."""
    effort = np.asarray(effort, dtype=float)
    n = effort.shape[1]
    if meaning not in EFFORT_MEANINGS:
        raise ConfigError("effort.meaning", f"one of {', '.join(EFFORT_MEANINGS)}; got "
                                            f"{short(meaning)}")
    if meaning == "commanded_no_gravity":
        return effort + gravity
    if meaning != "current":
        return effort
    factors = []
    for name, value in (("effort.torque_constant", torque_constant),
                        ("effort.gear_ratio", gear_ratio)):
        arr = np.asarray([] if value is None else value, dtype=float).reshape(-1)
        if arr.size == 1:
            arr = np.full(n, arr[0])
        if arr.size != n or not np.all(np.isfinite(arr) & (arr > 0)):
            raise ConfigError(name, f"effort.meaning current needs one value > 0 per joint "
                                    f"({n}) or one for all, got {short(value)}")
        factors.append(arr)
    return effort * factors[0] * factors[1]


def _unknowns(model: RigidBodyModel, spec: Spec, friction: bool):
    """The unknowns of ``spec`` and, for the base form, the structural analysis."""
    out, base = [], None
    if friction and not spec.payload_only:
        out += [Unknown(f"viscous {j}", "viscous", float(model.viscous[i]), joint=i)
                for i, j in enumerate(model.joints)]
        out += [Unknown(f"coulomb {j}", "coulomb", float(model.coulomb[i]), joint=i)
                for i, j in enumerate(model.joints)]
    tree = model.tree
    if spec.payload_only or spec.payload:
        frame = spec.payload
        if frame not in tree.frames or tree.frames[frame][0] < 0:
            raise ConfigError("payload.frame", f"{short(frame)} is no link or frame the joints "
                                               f"move")
        prior = tree.payloads.get(frame)
        theta = np.zeros(10) if prior is None else _frame_params(tree, frame, prior)
        out += [Unknown(f"payload {PARAMETERS[k]}", "payload", float(theta[k]), link=frame,
                        index=k) for k in range(10)]
    if spec.payload_only or spec.inertia == "none":
        return out, base
    if spec.inertia == "scale":
        links = list(spec.links) or [name for name in model.robot.links
                                     if _moves(model, name)]
        for name in links:
            if not _moves(model, name):
                raise ConfigError("--links", f"{short(name)} is no link with an <inertial> a "
                                             f"listed joint moves")
            out.append(Unknown(f"scale {name}", "scale",
                               float(tree.inertia_scale.get(name, 1.0)), link=name))
        return out, base
    if spec.inertia != "base":
        raise ConfigError("--inertia", f"one of {', '.join(INERTIA_FORMS)}; got "
                                       f"{short(spec.inertia)}")
    bodies = moving_bodies(model)
    independent, dependent, K = structural_base(model, [b for b, _ in bodies])
    for c in independent:
        b, link = bodies[c // 10]
        out.append(Unknown(f"{link} {PARAMETERS[c % 10]}", "body", float(tree.base[b, c % 10]),
                           link=link, body=b, index=c % 10))
    return out, (bodies, independent, dependent, K)


def _moves(model: RigidBodyModel, link: str) -> bool:
    b, _ = model.tree.link_params(link)
    return b >= 0 and model.tree.rows[b, ACTIVE] >= 0       # a listed joint moves it


def _frame_params(tree, frame, body_params):
    """A payload's 10 parameters (in its body) back about its frame's origin, frame axes."""
    _, R, p = tree.frames[frame]
    # shift_params is linear: invert it on the 10 unit vectors
    A = np.stack([shift_params(e, R, p) for e in np.eye(10)], axis=1)
    return np.linalg.solve(A, body_params)


def _column(reg: WindowRegressor, u: Unknown, viscous, coulomb) -> np.ndarray:
    if u.kind == "viscous":
        col = np.zeros_like(viscous)
        col[:, u.joint] = viscous[:, u.joint]
        return col
    if u.kind == "coulomb":
        col = np.zeros_like(coulomb)
        col[:, u.joint] = coulomb[:, u.joint]
        return col
    if u.kind == "scale":
        return reg.link_column(u.link)
    if u.kind == "body":
        return reg.body_column(u.body, u.index)
    return reg.frame_column(u.link, u.index)


def identify(model: RigidBodyModel, t, q, effort, passive=None, spec: Spec | None = None,
             mask=None) -> Identified:
    """Fit ``spec``'s unknowns on one stretch: stamps ``t`` (s), positions ``q`` and efforts
    (samples x the model's joints), the passive joints' positions (or None); ``mask``:
    samples to leave out (False). FitRefused when the data cannot support the fit."""
    spec = spec or Spec()
    if spec.effort not in EFFORT_MEANINGS:
        raise ConfigError("effort.meaning", f"one of {', '.join(EFFORT_MEANINGS)}; got "
                                            f"{short(spec.effort)}")
    reg = WindowRegressor(model, t, q, np.zeros_like(np.asarray(q, dtype=float)), passive,
                          spec.window, spec.stride, spec.max_gap, mask, spec.velocity_half)
    tau = torque_from_effort(spec.effort, effort, reg.gravity(), spec.torque_constant,
                             spec.gear_ratio)
    # a command holds from its sample to the next; a measured torque (a sensor's sample of a
    # signal that moves with the friction between samples) is interpolated like the positions
    held = spec.effort != "measured"
    reg.tau, reg.y = tau, (reg.windows.Z if held else reg.windows.A0) @ tau
    notes = []
    friction = spec.effort != "measured"
    if spec.friction and not friction:
        notes.append("friction not identified: measured link-side torques do not contain it")
    unknowns, base = _unknowns(model, spec, spec.friction and friction)
    if not unknowns:
        raise FitRefused("nothing to fit (friction off and no inertial form)")
    viscous, coulomb = reg.viscous_column(), reg.coulomb_column(model.friction_width)
    r0 = reg.y - reg.prediction()
    if friction:
        r0 = r0 - viscous * model.viscous - coulomb * model.coulomb
    X = np.stack([_column(reg, u, viscous, coulomb) for u in unknowns], axis=2)
    sigma_q = np.broadcast_to(np.asarray(spec.encoder_noise, dtype=float), (model.n,)) \
        if spec.encoder_noise is not None else encoder_noise(t, q)
    noise = np.sqrt(np.mean(reg.noise_level(sigma_q) ** 2, axis=0))
    prior = np.array([u.prior for u in unknowns])
    lags = 3 * (int(np.ceil(spec.window / (spec.stride * np.median(np.diff(t))))) + 1)
    fit = solve(X, r0, prior, noise, lags, spec.ratio, spec.outlier)
    value = prior + fit.delta
    pay = [i for i, u in enumerate(unknowns) if u.kind == "payload"]
    payload = _physical_payload(fit, value, pay, spec.payload, notes) if pay else None
    used = fit.used
    return Identified(model=model, spec=spec, unknowns=unknowns, value=value, se=fit.se, fit=fit,
                      prior_rms=np.sqrt(np.mean(r0[used] ** 2, axis=0)),
                      residual_rms=np.sqrt(np.mean(fit.residual[used] ** 2, axis=0)),
                      noise_rms=noise, encoder_noise=np.asarray(sigma_q, dtype=float),
                      windows=int(used.sum()), notes=notes, payload_fitted=payload,
                      window_times=np.asarray(t, dtype=float)[reg.windows.ends])


def _physical_payload(fit, value, pay, frame, notes):
    """(mass, com, inertia about the com) of the fitted payload: a mass the data put at or
    below zero is refused; an inertia about the centre of mass that is no rigid body's (a
    small load is nearly a point mass, and its fitted moments scatter around zero) is
    written as a point mass's (zero), said in a note."""
    mass, com, inertia = _payload_from(value[pay])
    if not mass > 0:
        raise FitRefused(f"payload at {frame}: the fitted mass is {mass:.4g} kg (standard "
                         f"error {fit.se[pay[0]]:.2g}): no payload the data can see")
    if np.any(inertia != 0):
        try:
            check_inertia(inertia, _raise)
        except FitRefused as err:
            notes.append(f"payload inertia about its centre of mass is no rigid body's "
                         f"({err}): written as a point mass")
            inertia = np.zeros((3, 3))
    return mass, com, inertia


def _raise(message: str):
    raise FitRefused(message)

