"""The Pinocchio reference of an arm model (ROS-free): the same rigid-body terms as
:class:`.model.RigidBodyModel`, computed by Pinocchio's own algorithms (crba,
computeCoriolisMatrix, computeGeneralizedGravity, rnea, computeFrameJacobian) on its own
reading of the same URDF. The tests hold the compiled dynamics to it; a simulation may use it
as the "true" arm.

Pinocchio reads every movable joint as a free coordinate (``mimic=False``): the terms are
computed for the whole tree at the moving joints' positions and velocities the model's
coordinate map gives (listed joints, passive positions, mimic joints following theirs) and
reduced to the listed joints with the same map G (v_tree = G v): M = G' M_tree G,
C = G' C_tree G, g = G' g_tree, tau = G' tau_tree, J = J_tree G. The armature comes from the
model (urdfdom ignores the attribute); payloads are added here to Pinocchio's own inertias at
Pinocchio's own frame placements.
"""
from __future__ import annotations

import math
import os
import tempfile

import numpy as np

from ..core.errors import ConfigError, short
from .model import RigidBodyModel
from .tree import ARMATURE


def pinocchio_model(text: str, param: str = "robot_description"):
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


class PinocchioReference:
    """Pinocchio's terms for ``model`` (built from the URDF ``text`` it was built from)."""

    def __init__(self, model: RigidBodyModel, text: str):
        import pinocchio as pin
        self._pin, self.model = pin, model
        self.pin_model = pm = pinocchio_model(text)
        names = model.moving_joints
        ids = [pm.getJointId(j) for j in names]
        if any(i >= pm.njoints for i in ids):
            raise ConfigError("robot_description", "Pinocchio's model lacks a moving joint")
        self._iq = [pm.joints[i].idx_q for i in ids]
        self._nq = [pm.joints[i].nq for i in ids]
        P = np.zeros((pm.nv, len(names)))                 # v_pin = P v_tree
        for k, i in enumerate(ids):
            P[pm.joints[i].idx_v, k] = 1.0
        self._P = P
        self.G = P @ model.velocity_map                   # v_pin = G v
        pm.armature = P @ model.tree.rows[:, ARMATURE]
        self.data = pm.createData()

    def add_payload(self, frame: str, mass: float, com, inertia) -> None:
        """A payload (mass, centre of mass, 3 x 3 inertia about it, in ``frame``'s axes) added
        to the inertia of the joint that carries Pinocchio's frame ``frame``."""
        pin, pm = self._pin, self.pin_model
        f = pm.frames[pm.getFrameId(frame)]
        X = f.placement
        R = X.rotation
        body = pin.Inertia(float(mass), R @ np.asarray(com, float) + X.translation,
                           R @ np.asarray(inertia, float) @ R.T)
        pm.inertias[f.parentJoint] = pm.inertias[f.parentJoint] + body
        self.data = pm.createData()

    # -- coordinates ------------------------------------------------------------------------
    def configuration(self, q, passive=None) -> np.ndarray:
        qf, _ = self.model.full_state(q, None, passive)
        out = self._pin.neutral(self.pin_model)
        for iq, nq, x in zip(self._iq, self._nq, qf):
            if nq == 2:                                    # continuous: (cos, sin)
                out[iq], out[iq + 1] = math.cos(x), math.sin(x)
            else:
                out[iq] = x
        return out

    def _reduce(self, A):
        return self.G.T @ A @ self.G if np.ndim(A) == 2 else self.G.T @ A

    # -- terms ------------------------------------------------------------------------------
    def mass_matrix(self, q, passive=None) -> np.ndarray:
        M = np.array(self._pin.crba(self.pin_model, self.data, self.configuration(q, passive)))
        M = np.triu(M) + np.triu(M, 1).T
        return self._reduce(M)

    def coriolis_matrix(self, q, v, passive=None) -> np.ndarray:
        C = self._pin.computeCoriolisMatrix(self.pin_model, self.data,
                                            self.configuration(q, passive), self.G @ v)
        return self._reduce(np.array(C))

    def gravity(self, q, passive=None) -> np.ndarray:
        g = self._pin.computeGeneralizedGravity(self.pin_model, self.data,
                                                self.configuration(q, passive))
        return self._reduce(np.array(g))

    def rnea(self, q, v, a, passive=None) -> np.ndarray:
        """M a + C v + g (no friction)."""
        tau = self._pin.rnea(self.pin_model, self.data, self.configuration(q, passive),
                             self.G @ v, self.G @ a)
        return self._reduce(np.array(tau))

    def forward_dynamics(self, q, v, tau, passive=None) -> np.ndarray:
        """a = M^-1 (tau - C v - g) (no friction)."""
        rhs = np.asarray(tau, float) - self.rnea(q, v, np.zeros_like(v), passive)
        return np.linalg.solve(self.mass_matrix(q, passive), rhs)

    def momentum_terms(self, q, v, mass: bool = True, passive=None):
        """(M, Mdot = C + C', C' v, g) as :meth:`.model.RigidBodyModel.momentum_terms`, from
        crba, computeCoriolisMatrix and computeGeneralizedGravity (what the estimators called
        per sample before the compiled dynamics)."""
        C = self.coriolis_matrix(q, v, passive)
        return (self.mass_matrix(q, passive) if mass else None), C + C.T, C.T @ v, \
            self.gravity(q, passive)

    def jacobian(self, frame: str, q, passive=None) -> np.ndarray:
        pin, pm = self._pin, self.pin_model
        J = pin.computeFrameJacobian(pm, self.data, self.configuration(q, passive),
                                     pm.getFrameId(frame), pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return np.array(J) @ self.G
