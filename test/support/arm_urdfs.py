"""URDF texts for the arm room's tests and benchmarks: a chain of any length, and a small
arm with a parallel gripper whose second finger is a <mimic> of the first, random
(seeded) inertias, rotated joint frames and inertial frames, a continuous joint, a
prismatic joint in the chain, fixed links and a passive side branch."""
from __future__ import annotations

import numpy as np


def _v(*values) -> str:
    return " ".join(repr(float(x)) for x in values)


def inertial(m, com=(0, 0, 0), moments=(0.01, 0.01, 0.01), rpy=(0, 0, 0), off=(0, 0, 0)) -> str:
    """An <inertial> with principal moments ``moments`` plus products ``off`` (ixy, ixz,
    iyz), its frame at ``com`` rotated by ``rpy``."""
    a, b, c = moments
    xy, xz, yz = off
    return (f'<inertial><origin xyz="{_v(*com)}" rpy="{_v(*rpy)}"/><mass value="{_v(m)}"/>'
            f'<inertia ixx="{_v(a)}" ixy="{_v(xy)}" ixz="{_v(xz)}" iyy="{_v(b)}" iyz="{_v(yz)}" '
            f'izz="{_v(c)}"/></inertial>')


def link(name, body="") -> str:
    return f'<link name="{name}">{body}</link>'


def joint(name, kind, parent, child, xyz=(0, 0, 0), rpy=(0, 0, 0), axis=(0, 0, 1),
          extra="") -> str:
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{_v(*xyz)}" rpy="{_v(*rpy)}"/>'
            f'<axis xyz="{_v(*axis)}"/><limit lower="-3" upper="3" effort="100" velocity="5"/>'
            f'{extra}</joint>')


def chain(n: int) -> str:
    """n revolute joints in a chain, axes alternating y and z, 1 kg links."""
    parts = ['<robot name="chain">', link("l0")]
    for i in range(1, n + 1):
        parts.append(joint(f"j{i}", "revolute", f"l{i - 1}", f"l{i}", (0, 0, 0.1), (0.1, 0, 0),
                           (0, i % 2, (i + 1) % 2)))
        parts.append(link(f"l{i}", inertial(1.0, (0, 0, 0.05))))
    return "".join(parts + ["</robot>"])


def _random_inertial(rng, scale=1.0) -> str:
    m = float(rng.uniform(0.3, 3.0)) * scale
    a, b = rng.uniform(0.2, 1.0, 2) * 0.01 * scale
    c = float(rng.uniform(abs(a - b) + 1e-4, a + b))          # the triangle inequality
    return inertial(m, tuple(rng.uniform(-0.05, 0.05, 3)), (float(a), float(b), c),
                    tuple(rng.uniform(-np.pi, np.pi, 3)))


def gripper_arm(seed: int = 0, multiplier: float = -1.0, offset: float = 0.01,
                camera: bool = True) -> str:
    """A 5-joint arm (revolute, continuous, prismatic among them, rotated frames), a fixed
    flange and hand, two prismatic fingers (finger_2 a <mimic> of finger_1 with
    ``multiplier`` and ``offset``), a tool frame, and (``camera``) a 'pan' joint on a side
    branch of link_2 carrying a camera."""
    rng = np.random.default_rng(seed)

    def origin():
        return tuple(rng.uniform(-0.1, 0.1, 2)) + (float(rng.uniform(0.1, 0.3)),), \
            tuple(rng.uniform(-1.0, 1.0, 3))

    parts = ['<robot name="gripper_arm">', link("base", _random_inertial(rng))]
    kinds = ["revolute", "revolute", "continuous", "prismatic", "revolute"]
    axes = [(0, 0, 1), (0, 1, 0), (0.3, -0.5, 0.8), (0, 0, 1), (1, 0, 0)]
    for i, (kind, axis) in enumerate(zip(kinds, axes), start=1):
        xyz, rpy = origin()
        parts.append(joint(f"joint_{i}", kind, "base" if i == 1 else f"link_{i - 1}",
                           f"link_{i}", xyz, rpy, axis,
                           f'<dynamics damping="0.5" friction="0.3" armature="{0.02 * i!r}"/>'))
        parts.append(link(f"link_{i}", _random_inertial(rng)))
    parts += [joint("flange", "fixed", "link_5", "flange_link", (0, 0, 0.05), (0, 0, 0.3)),
              link("flange_link", _random_inertial(rng, 0.2)),
              joint("hand_joint", "fixed", "flange_link", "hand", (0, 0, 0.03), (0.1, 0, 0)),
              link("hand", _random_inertial(rng, 0.5)),
              joint("tcp_joint", "fixed", "hand", "tcp", (0, 0, 0.1)), link("tcp"),
              joint("finger_1", "prismatic", "hand", "finger_link_1", (0, 0.02, 0.06),
                    axis=(0, 1, 0), extra='<dynamics damping="0.0" armature="0.01"/>'),
              link("finger_link_1", _random_inertial(rng, 0.1)),
              joint("finger_2", "prismatic", "hand", "finger_link_2", (0, -0.02, 0.06),
                    axis=(0, -1, 0),
                    extra=f'<mimic joint="finger_1" multiplier="{multiplier!r}" offset="{offset!r}"/>'
                          f'<dynamics damping="0.0" armature="0.01"/>'),
              link("finger_link_2", _random_inertial(rng, 0.1))]
    if camera:
        parts += [joint("pan", "revolute", "link_2", "camera", (0.05, 0, 0.1), (0, 0.4, 0),
                    axis=(0, 0, 1)),
                  link("camera", _random_inertial(rng, 0.3))]
    return "".join(parts + ["</robot>"])
