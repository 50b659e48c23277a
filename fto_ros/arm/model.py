"""An arm's rigid-body dynamics from its URDF, through Pinocchio (ROS-free).

    M(q) a + C(q, v) v + g(q) + tau_f(v) = tau + tau_ext,     p = M(q) v,
    p' = tau + C(q, v)^T v - g(q) - tau_f(v) + tau_ext        (Mdot = C + C^T)

for the joints a user lists, in the user's order (the others are locked at given
positions: Pinocchio's reduced model). tau_f is the friction model per joint, viscous and
Coulomb with a smooth sign: tau_f = b v + f_c tanh(v / w); by default b and f_c are the
URDF's ``<dynamics damping friction>``. The armature (a motor's rotor inertia reflected
through its gear, added to M's diagonal) is ``<dynamics armature>`` when the URDF gives it
(an attribute urdfdom ignores), or given.

Refusals are one line naming the parameter (``ConfigError``): a source over the size limit
(checked before anything is parsed), XML that does not parse, a URDF Pinocchio cannot read
(urdfdom's own first error line is quoted), joints the model does not have, joints of a type
an arm estimator cannot use (floating, planar, fixed), movable joints neither listed nor
locked, non-finite or negative friction.
"""
from __future__ import annotations

import math
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..core import jit
from ..core.errors import ConfigError, short
from . import steps_compiled as compiled

#: largest URDF accepted, in bytes (file or string); real arm URDFs are well under 1 MB
MAX_URDF_BYTES = 4 * 1024 * 1024
#: most joints a URDF may declare
MAX_JOINTS = 512
#: default width w of the Coulomb friction's smooth sign tanh(v / w), rad/s
DEFAULT_FRICTION_WIDTH = 0.02


def _read_source(urdf: str | os.PathLike | None, robot_description: str | None) -> tuple[str, str]:
    """(xml text, parameter name) of exactly one source, with the size checked first."""
    if (urdf is None) == (robot_description is None):
        raise ConfigError("plant.urdf", "give a URDF file (plant.urdf) or the robot_description "
                                        "string, exactly one of them")
    if robot_description is not None:
        if not isinstance(robot_description, str):
            raise ConfigError("robot_description", f"must be a string, got "
                                                   f"{type(robot_description).__name__}")
        if len(robot_description) > MAX_URDF_BYTES:
            raise ConfigError("robot_description", f"{len(robot_description)} characters: larger "
                                                   f"than the {MAX_URDF_BYTES} a URDF may have")
        return robot_description, "robot_description"
    path = Path(urdf)
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise ConfigError("plant.urdf", f"{short(str(path))} is not a file")
        if size > MAX_URDF_BYTES:
            raise ConfigError("plant.urdf", f"{short(str(path))} has {size} bytes: larger than "
                                            f"the {MAX_URDF_BYTES} a URDF may have")
        with open(path, "rb") as f:
            data = f.read(MAX_URDF_BYTES + 1)
    except OSError as err:
        raise ConfigError("plant.urdf", f"cannot read {short(str(path))}: {err.strerror}") from None
    if len(data) > MAX_URDF_BYTES:
        raise ConfigError("plant.urdf", f"{short(str(path))} is larger than {MAX_URDF_BYTES} bytes")
    try:
        return data.decode("utf-8"), "plant.urdf"
    except UnicodeDecodeError:
        raise ConfigError("plant.urdf", f"{short(str(path))} is not UTF-8 text") from None


def _armatures(root: ET.Element, param: str) -> dict[str, float]:
    """joint name -> the ``armature`` attribute of its ``<dynamics>`` (non-standard)."""
    out = {}
    for j in root.findall("joint"):
        dyn = j.find("dynamics")
        if dyn is not None and "armature" in dyn.attrib:
            try:
                x = float(dyn.attrib["armature"])
            except ValueError:
                x = math.nan
            if not (math.isfinite(x) and x >= 0):
                raise ConfigError(param, f"joint {short(j.get('name'))}: the armature must be a "
                                         f"number >= 0, got {short(dyn.attrib['armature'])}")
            out[j.get("name")] = x
    return out


def _check_xml(text: str, param: str) -> ET.Element:
    """The parsed <robot> element (Python's expat refuses entity expansion bombs)."""
    if "\x00" in text:
        raise ConfigError(param, "not a URDF: the text holds a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as err:
        raise ConfigError(param, f"not a URDF: not encodable as UTF-8 ({err.reason} at "
                                 f"character {err.start})") from None
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise ConfigError(param, f"not a URDF: the XML does not parse ({err})") from None
    if root.tag != "robot":
        raise ConfigError(param, f"not a URDF: the root element is <{short(root.tag)}>, "
                                 f"not <robot>")
    joints = root.findall("joint")
    if len(joints) > MAX_JOINTS:
        raise ConfigError(param, f"{len(joints)} joints: more than the {MAX_JOINTS} accepted")
    return root


def _pinocchio_model(text: str, param: str):
    """pin.Model of the URDF text; urdfdom's error lines go into the message, not stderr."""
    import pinocchio as pin
    with tempfile.TemporaryFile(mode="w+b") as err_file:
        saved = os.dup(2)
        os.dup2(err_file.fileno(), 2)
        try:
            model = pin.buildModelFromXML(text)
            failure = None
        except Exception as exc:          # ValueError / RuntimeError from the bindings
            model, failure = None, exc
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        err_file.seek(0)
        printed = err_file.read(4000).decode("utf-8", "replace")
    if failure is not None:
        lines = [ln.strip() for ln in printed.splitlines() if ln.strip().startswith("Error:")]
        why = lines[0][len("Error:"):].strip() if lines else short(failure)
        raise ConfigError(param, f"Pinocchio cannot read this URDF: {why}")
    return model


def _as_vector(values, n: int, name: str, *, nonnegative: bool = False) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be a list of numbers, got {short(values)}") from None
    if arr.size == 1 and n > 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise ConfigError(name, f"needs one value per joint ({n}), got {arr.size}")
    if not np.all(np.isfinite(arr)) or (nonnegative and np.any(arr < 0)):
        raise ConfigError(name, f"must be finite{' and >= 0' if nonnegative else ''}, got "
                                f"{short(arr.tolist())}")
    return arr


class RigidBodyModel:
    """The dynamics of the listed joints of an arm (see the module doc).

    Every method takes and returns float64 arrays in the order of ``joints``. Call
    :func:`load_model` to build one from parameters."""

    def __init__(self, full_model, joints: Sequence[str], locked: Mapping[str, float],
                 viscous=None, coulomb=None, friction_width: float = DEFAULT_FRICTION_WIDTH,
                 armature=None, joints_param: str = "plant.joints"):
        import pinocchio as pin
        self._pin = pin
        joints = list(joints) if not isinstance(joints, str) else [joints]
        if not joints or not all(isinstance(j, str) and j for j in joints):
            raise ConfigError(joints_param, f"must be a non-empty list of joint names, got "
                                            f"{short(joints)}")
        twice = sorted({j for j in joints if joints.count(j) > 1})
        if twice:
            raise ConfigError(joints_param, f"joints listed twice: {', '.join(twice)}")
        names = list(full_model.names)[1:]                # [0] is 'universe'
        fixed = {full_model.frames[i].name for i in range(len(full_model.frames))
                 if full_model.frames[i].type == pin.FrameType.FIXED_JOINT}
        missing = [j for j in joints if j not in names]
        if missing:
            what = [f"{j} (a fixed joint)" if j in fixed else j for j in missing]
            raise ConfigError(joints_param, f"the URDF has no movable joint(s) {', '.join(what)} "
                                            f"(its movable joints: {short(names)})")
        bad = [f"{j} ({full_model.joints[full_model.getJointId(j)].shortname()})" for j in joints
               if full_model.joints[full_model.getJointId(j)].nv != 1]
        if bad:
            raise ConfigError(joints_param, f"joint(s) {', '.join(bad)} are not revolute, "
                                            f"continuous or prismatic joints of one degree of "
                                            f"freedom")
        locked = dict(locked or {})
        unknown = [j for j in locked if j not in names]
        if unknown:
            raise ConfigError("plant.locked_joints", f"the URDF has no joint(s) "
                                                     f"{', '.join(map(str, unknown))}")
        both = [j for j in locked if j in joints]
        if both:
            raise ConfigError("plant.locked_joints", f"joint(s) {', '.join(both)} are also in "
                                                     f"{joints_param}: a joint moves or is locked")
        loose = [j for j in names if j not in joints and j not in locked]
        if loose:
            raise ConfigError(joints_param, f"movable joint(s) {', '.join(loose)} are neither "
                                            f"listed here nor locked (plant.locked_joints: "
                                            f"name: position)")
        q_ref = pin.neutral(full_model)
        for name, value in locked.items():
            try:
                x = float(value)
            except (TypeError, ValueError):
                x = math.nan
            if not math.isfinite(x):
                raise ConfigError("plant.locked_joints", f"{name}: the position must be a finite "
                                                         f"number, got {short(value)}")
            jid = full_model.getJointId(name)
            self._set_coordinate(full_model, jid, q_ref, x)
        lock_ids = [full_model.getJointId(j) for j in locked]
        model = pin.buildReducedModel(full_model, lock_ids, q_ref) if lock_ids else full_model
        self.model, self.data = model, model.createData()
        self.joints = tuple(joints)
        self.n = n = len(joints)
        ids = [model.getJointId(j) for j in joints]
        self._iq = [model.joints[i].idx_q for i in ids]
        self._nq = [model.joints[i].nq for i in ids]
        self._iv = np.array([model.joints[i].idx_v for i in ids])
        self._q_pin = pin.neutral(model)
        if armature is not None:
            arm = (np.array([armature.get(j, 0.0) for j in joints]) if isinstance(armature, dict)
                   else _as_vector(armature, n, "plant.armature", nonnegative=True))
            model.armature[self._iv] = arm
            self.data = model.createData()
        self.armature = np.array(model.armature[self._iv])
        self.viscous = (_as_vector(model.damping[self._iv], n, "plant.viscous_friction")
                        if viscous is None else
                        _as_vector(viscous, n, "plant.viscous_friction", nonnegative=True))
        self.coulomb = (_as_vector(model.friction[self._iv], n, "plant.coulomb_friction")
                        if coulomb is None else
                        _as_vector(coulomb, n, "plant.coulomb_friction", nonnegative=True))
        w = float(friction_width) if isinstance(friction_width, (int, float)) else math.nan
        if not (math.isfinite(w) and w > 0):
            raise ConfigError("plant.friction_width", f"must be a finite number > 0, got "
                                                      f"{short(friction_width)}")
        self.friction_width = w
        self.effort_limit = np.array(model.effortLimit[self._iv])
        self._perm = np.ix_(self._iv, self._iv)
        self._identity = bool(model.nv == n and np.array_equal(self._iv, np.arange(n)))
        self._lower = np.tril_indices(model.nv, -1)

    # -- coordinates ------------------------------------------------------------------------
    @staticmethod
    def _set_coordinate(model, jid: int, q_pin: np.ndarray, x: float) -> None:
        j = model.joints[jid]
        if j.nq == 2:                                    # continuous: (cos, sin)
            q_pin[j.idx_q], q_pin[j.idx_q + 1] = math.cos(x), math.sin(x)
        elif j.nq == 1:
            q_pin[j.idx_q] = x

    def _q(self, q) -> np.ndarray:
        out = self._q_pin
        for iq, nq, x in zip(self._iq, self._nq, q):
            if nq == 2:
                out[iq], out[iq + 1] = math.cos(x), math.sin(x)
            else:
                out[iq] = x
        return out

    def _v(self, v) -> np.ndarray:
        out = np.zeros(self.model.nv)
        out[self._iv] = v
        return out

    # -- dynamics ---------------------------------------------------------------------------
    def mass_matrix(self, q) -> np.ndarray:
        """M(q), symmetric (Pinocchio's CRBA fills the upper triangle only)."""
        M = self._pin.crba(self.model, self.data, self._q(q))
        M = np.triu(M) + np.triu(M, 1).T
        return M[self._perm]

    def coriolis_matrix(self, q, v) -> np.ndarray:
        """C(q, v) with Mdot = C + C^T (Pinocchio's Christoffel form)."""
        C = self._pin.computeCoriolisMatrix(self.model, self.data, self._q(q), self._v(v))
        return np.array(C[self._perm])

    def gravity(self, q) -> np.ndarray:
        return np.array(self._pin.computeGeneralizedGravity(self.model, self.data,
                                                            self._q(q))[self._iv])

    def friction(self, v) -> np.ndarray:
        """tau_f(v) = b v + f_c tanh(v / w)."""
        v = np.asarray(v, dtype=float)
        return self.viscous * v + self.coulomb * np.tanh(v / self.friction_width)

    def coriolis(self, q, v) -> np.ndarray:
        """C(q, v) v."""
        return self.coriolis_matrix(q, v) @ np.asarray(v, dtype=float)

    def inverse_dynamics(self, q, v, a) -> np.ndarray:
        """tau = M a + C v + g + tau_f (no external torque)."""
        tau = self._pin.rnea(self.model, self.data, self._q(q), self._v(v), self._v(a))
        return np.array(tau[self._iv]) + self.friction(v)

    def forward_dynamics(self, q, v, tau) -> np.ndarray:
        """a = M^-1 (tau - C v - g - tau_f); tau includes any external torque."""
        t = self._v(np.asarray(tau, dtype=float) - self.friction(v))
        return np.array(self._pin.aba(self.model, self.data, self._q(q), self._v(v), t)[self._iv])

    def momentum(self, q, v) -> np.ndarray:
        """p = M(q) v."""
        return self.mass_matrix(q) @ np.asarray(v, dtype=float)

    def jacobian(self, link: str, q) -> np.ndarray:
        """6 x n Jacobian of the origin of ``link``'s frame, (linear; angular) in world-aligned
        axes: the joint torques of a wrench (f; m) there are J^T (f; m)."""
        pin = self._pin
        if not isinstance(link, str) or not self.model.existFrame(link):
            raise ConfigError("contact.link", f"the URDF has no link or frame {short(link)}")
        fid = self.model.getFrameId(link)
        J = pin.computeFrameJacobian(self.model, self.data, self._q(q), fid,
                                     pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return np.array(J[:, self._iv])

    def wrench(self, link: str, q, tau_ext, force_only: bool = False) -> np.ndarray:
        """The wrench (f; m) at the origin of ``link``'s frame, world axes, whose joint torques
        J^T (f; m) best match ``tau_ext`` (least squares; with ``force_only`` a pure force,
        m = 0): the contact wrench a tau_ext estimate implies, if the contact is on that link."""
        J = self.jacobian(link, q)
        A = J[:3].T if force_only else J.T
        w = np.linalg.lstsq(A, np.asarray(tau_ext, dtype=float), rcond=1e-9)[0]
        return np.concatenate([w, np.zeros(3)]) if force_only else w

    def momentum_terms(self, q, v, mass: bool = True):
        """(M, Mdot, C^T v, g) at (q, v): what the estimators' steps take from the model
        (the values of mass_matrix, coriolis_matrix and gravity, with one conversion of q and
        v: this is called twice per sample); M is None without ``mass``."""
        pin, model, data = self._pin, self.model, self.data
        qp, v = self._q(q), np.asarray(v, dtype=float)
        if self._identity and jit.ENABLED:           # the same values, compiled
            Mp = pin.crba(model, data, qp) if mass else data.M
            C = pin.computeCoriolisMatrix(model, data, qp, v)
            M, Md, ctv = compiled.momentum_post(Mp, C, v, mass)
            g = np.array(pin.computeGeneralizedGravity(model, data, qp))
            return (M if mass else None), Md, ctv, g
        M = None
        if mass:
            M = np.array(pin.crba(model, data, qp))
            M[self._lower] = M.T[self._lower]             # CRBA fills the upper triangle
        C = np.array(pin.computeCoriolisMatrix(model, data, qp, self._v(v)))
        g = np.array(pin.computeGeneralizedGravity(model, data, qp))
        if not self._identity:
            M = None if M is None else M[self._perm]
            C, g = C[self._perm], g[self._iv]
        return M, C + C.T, C.T @ v, g


def load_model(joints: Sequence[str] | None, *, urdf: str | os.PathLike | None = None,
               robot_description: str | None = None, locked_joints: Mapping[str, float] | None = None,
               viscous_friction=None, coulomb_friction=None,
               friction_width: float = DEFAULT_FRICTION_WIDTH, armature=None) -> RigidBodyModel:
    """A :class:`RigidBodyModel` from a URDF file (``plant.urdf``) or string
    (``robot_description``), the joints to use (``plant.joints``; None: every joint of one
    degree of freedom, in the URDF's tree order) and the positions of the joints locked
    (``plant.locked_joints``); friction and armature per joint (None: the URDF's)."""
    text, param = _read_source(urdf, robot_description)
    root = _check_xml(text, param)
    if armature is None:
        armature = _armatures(root, param)
    full = _pinocchio_model(text, param)
    if joints is None:
        joints = [full.names[i] for i in range(1, full.njoints) if full.joints[i].nv == 1
                  and full.names[i] not in (locked_joints or {})]
    return RigidBodyModel(full, joints, locked_joints or {}, viscous_friction, coulomb_friction,
                          friction_width, armature)
