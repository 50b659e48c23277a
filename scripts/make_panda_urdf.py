"""Write urdf/panda_gripper.urdf: a 7-joint arm of the Franka Emika Panda's class with its
parallel gripper, the arm class of docs/arm_class.md (fto-simulate --urdf).

Every number is a published fact, written out here by us (no meshes, no xacro):

- kinematics (joint origins, z axes): the Panda's, franka_description
  robots/fer/kinematics.yaml (frankaemika/franka_description; the FR3 has the same);
- joint limits (position, velocity, effort): franka_ros franka_description
  robots/panda/joint_limits.yaml (87 Nm on joints 1-4, 12 Nm on joints 5-7);
- link masses, centres of mass and inertia tensors of links 0-7, the hand and the fingers:
  franka_ros franka_description robots/common/inertial.yaml, which cites their source,
  C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca, "Dynamic identification of
  the Franka Emika Panda robot with retrieval of feasible parameters using penalty-based
  optimization", IEEE RA-L 4(4), 2019. Joint 7's inertia with the hand is then about
  0.0067 kg m^2 (light distal links);
- the hand: fixed to the flange (link8, 0.107 m beyond joint 7) turned by -pi/4 about z; two
  prismatic fingers 0.0584 m from the hand's origin, along +y and -y, 0 to 0.04 m, 100 N,
  0.2 m/s, the second a <mimic> of the first (franka_description's franka_hand.xacro).

No <dynamics> (no friction, damping or armature): a real arm's URDF does not know them;
fto-simulate --friction adds friction to the simulated arm only.

    python scripts/make_panda_urdf.py > urdf/panda_gripper.urdf
"""
import math

import numpy as np

PI2 = "1.570796326794897"
# name, origin xyz, origin rpy, lower, upper (rad), velocity (rad/s), effort (Nm)
JOINTS = [
    ("joint1", "0 0 0.333", "0 0 0", -2.8973, 2.8973, 2.1750, 87),
    ("joint2", "0 0 0", f"-{PI2} 0 0", -1.7628, 1.7628, 2.1750, 87),
    ("joint3", "0 -0.316 0", f"{PI2} 0 0", -2.8973, 2.8973, 2.1750, 87),
    ("joint4", "0.0825 0 0", f"{PI2} 0 0", -3.0718, -0.0698, 2.1750, 87),
    ("joint5", "-0.0825 0.384 0", f"-{PI2} 0 0", -2.8973, 2.8973, 2.6100, 12),
    ("joint6", "0 0 0", f"{PI2} 0 0", -0.0175, 3.7525, 2.6100, 12),
    ("joint7", "0.088 0 0", f"{PI2} 0 0", -2.8973, 2.8973, 2.6100, 12),
]
# link: mass (kg), centre of mass (m), inertia about it (xx, yy, zz, xy, xz, yz; kg m^2)
INERTIALS = {
    "link0": (0.629769, (-0.041018, -0.00014, 0.049974),
              (0.00315, 0.00388, 0.004285, 8.2904e-07, 0.00015, 8.2299e-06)),
    "link1": (4.970684, (0.003875, 0.002081, -0.04762),
              (0.70337, 0.70661, 0.0091170, -0.00013900, 0.0067720, 0.019169)),
    "link2": (0.646926, (-0.003141, -0.02872, 0.003495),
              (0.0079620, 2.8110e-02, 2.5995e-02, -3.9250e-3, 1.0254e-02, 7.0400e-04)),
    "link3": (3.228604, (2.7518e-02, 3.9252e-02, -6.6502e-02),
              (3.7242e-02, 3.6155e-02, 1.0830e-02, -4.7610e-03, -1.1396e-02, -1.2805e-02)),
    "link4": (3.587895, (-5.317e-02, 1.04419e-01, 2.7454e-02),
              (2.5853e-02, 1.9552e-02, 2.8323e-02, 7.7960e-03, -1.3320e-03, 8.6410e-03)),
    "link5": (1.225946, (-1.1953e-02, 4.1065e-02, -3.8437e-02),
              (3.5549e-02, 2.9474e-02, 8.6270e-03, -2.1170e-03, -4.0370e-03, 2.2900e-04)),
    "link6": (1.666555, (6.0149e-02, -1.4117e-02, -1.0517e-02),
              (1.9640e-03, 4.3540e-03, 5.4330e-03, 1.0900e-04, -1.1580e-03, 3.4100e-04)),
    "link7": (7.35522e-01, (1.0517e-02, -4.252e-03, 6.1597e-02),
              (1.2516e-02, 1.0027e-02, 4.8150e-03, -4.2800e-04, -1.1960e-03, -7.4100e-04)),
    "hand": (0.73, (-0.01, 0.0, 0.03), (0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0)),
    "leftfinger": (0.015, (0.0, 0.0, 0.0), (2.375e-06, 2.375e-06, 7.5e-07, 0.0, 0.0, 0.0)),
    "rightfinger": (0.015, (0.0, 0.0, 0.0), (2.375e-06, 2.375e-06, 7.5e-07, 0.0, 0.0, 0.0)),
}
P = "panda_"


def check(name, inertia):
    """The tensor is positive definite and its principal moments satisfy the triangle
    inequality (what a physical body has); the script stops otherwise."""
    xx, yy, zz, xy, xz, yz = inertia
    ev = np.linalg.eigvalsh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))
    if not (ev[0] > 0 and ev[0] + ev[1] >= ev[2]):
        raise SystemExit(f"{name}: inertia not physical (principal moments {ev})")


def link(name):
    if name not in INERTIALS:
        return f'  <link name="{P}{name}"/>\n'
    m, c, inertia = INERTIALS[name]
    check(name, inertia)
    xx, yy, zz, xy, xz, yz = inertia
    return (f'  <link name="{P}{name}">\n'
            f'    <inertial>\n'
            f'      <origin xyz="{c[0]:.9g} {c[1]:.9g} {c[2]:.9g}" rpy="0 0 0"/>\n'
            f'      <mass value="{m:.9g}"/>\n'
            f'      <inertia ixx="{xx:.9g}" ixy="{xy:.9g}" ixz="{xz:.9g}" iyy="{yy:.9g}" '
            f'iyz="{yz:.9g}" izz="{zz:.9g}"/>\n'
            f'    </inertial>\n'
            f'  </link>\n')


def joint(name, kind, parent, child, xyz, rpy, axis=None, limit=None, mimic=None):
    out = [f'  <joint name="{P}{name}" type="{kind}">',
           f'    <parent link="{P}{parent}"/>', f'    <child link="{P}{child}"/>',
           f'    <origin xyz="{xyz}" rpy="{rpy}"/>']
    if axis:
        out.append(f'    <axis xyz="{axis}"/>')
    if limit:
        lo, hi, vel, effort = limit
        out.append(f'    <limit lower="{lo}" upper="{hi}" effort="{effort}" velocity="{vel}"/>')
    if mimic:
        out.append(f'    <mimic joint="{P}{mimic}" multiplier="1" offset="0"/>')
    out.append('  </joint>\n')
    return "\n".join(out)


def main():
    out = ['<?xml version="1.0"?>',
           '<!-- Generated by scripts/make_panda_urdf.py (fto_ros): a 7-joint arm of the Franka',
           '     Emika Panda\'s class with its parallel gripper. Kinematics and limits: the',
           '     published franka_description; link masses, centres of mass and inertias:',
           '     Gaz et al., IEEE RA-L 2019 (as in franka_ros inertial.yaml). No friction, no',
           '     meshes. -->',
           '<robot name="panda_gripper">', link("link0")]
    parent = "link0"
    for i, (name, xyz, rpy, lo, hi, vel, effort) in enumerate(JOINTS, 1):
        out.append(joint(name, "revolute", parent, f"link{i}", xyz, rpy, "0 0 1",
                         (lo, hi, vel, effort)))
        out.append(link(f"link{i}"))
        parent = f"link{i}"
    out.append(joint("joint8", "fixed", "link7", "link8", "0 0 0.107", "0 0 0"))
    out.append(link("link8"))
    out.append(joint("hand_joint", "fixed", "link8", "hand", "0 0 0",
                     f"0 0 {-math.pi / 4:.15f}"))
    out.append(link("hand"))
    out.append(joint("hand_tcp_joint", "fixed", "hand", "hand_tcp", "0 0 0.1034", "0 0 0"))
    out.append(link("hand_tcp"))
    out.append(link("leftfinger"))
    out.append(link("rightfinger"))
    out.append(joint("finger_joint1", "prismatic", "hand", "leftfinger", "0 0 0.0584", "0 0 0",
                     "0 1 0", (0.0, 0.04, 0.2, 100)))
    out.append(joint("finger_joint2", "prismatic", "hand", "rightfinger", "0 0 0.0584",
                     "0 0 0", "0 -1 0", (0.0, 0.04, 0.2, 100), mimic="finger_joint1"))
    out.append("</robot>")
    print("\n".join(out))


if __name__ == "__main__":
    main()
