"""The bag of an ``fto-simulate --urdf`` run: its topics, written and read back.

Topics (``SYS`` = ``--system``, default ``arm``); log time = the sample's actual instant:

- the stream (``--topic``, default ``/SYS/joint_states``; sensor_msgs/JointState, every
  joint that moves, the gripper's fingers too, in the URDF's order, as joint_state_broadcaster
  publishes them): header stamp = the actual instant (plus ``--stamp-noise``), position =
  the encoder, effort = the ``--effort`` meaning (0 on the fingers); lost messages are absent;
- ``/SYS/true_joint_states`` (JointState, every sample): the true position, velocity, and
  in effort the true external joint torque J^T F;
- ``/SYS/true_command`` (JointState, effort): the motor torque commanded at the sample (held
  until the next), gravity compensation included;
- ``/SYS/true_joint_torque`` (JointState, effort): the link-side joint torque tau_J =
  commanded - tau_f(v) at the sample;
- ``/SYS/true_contact`` (std_msgs/Float64MultiArray): [active (0/1), fx, fy, fz];
- ``/clock``.

The truth topics are stamped with the actual instant.
"""
from __future__ import annotations

import json

import numpy as np

from ..bag import BagReader, BagWriter
from ..models.arm import ArmRun
from ..models.simulate import to_ns

METADATA_KEY = "fto_ros.simulation"


def topic_names(system: str, stream: str | None = None) -> dict[str, str]:
    """The topics of a run recorded under ``system`` (``stream``: the JointState stream)."""
    return {"joint_states": stream or f"/{system}/joint_states",
            "true_joint_states": f"/{system}/true_joint_states",
            "true_command": f"/{system}/true_command",
            "true_joint_torque": f"/{system}/true_joint_torque",
            "true_contact": f"/{system}/true_contact", "clock": "/clock"}


def write_arm_bag(out, run: ArmRun, topics: dict[str, str], stamps: np.ndarray,
                  lost: np.ndarray, effort: np.ndarray, meta: dict,
                  overwrite: bool = False) -> dict[str, int]:
    """Write the bag (module doc); returns topic -> messages written (BagError on failure)."""
    names = list(run.names)
    tau_j = run.tau - run.friction
    with BagWriter(out, overwrite=overwrite,
                   custom_data={METADATA_KEY: json.dumps(meta, sort_keys=True)}) as bag:
        for k, t in enumerate(run.t):
            t_ns = to_ns(t)
            bag.clock(t_ns)
            if not lost[k]:
                bag.joint_state(topics["joint_states"], t_ns, int(stamps[k]), names,
                                position=run.q_measured[k], effort=effort[k])
            bag.joint_state(topics["true_joint_states"], t_ns, t_ns, names,
                            position=run.q[k], velocity=run.v[k], effort=run.tau_ext[k])
            bag.joint_state(topics["true_command"], t_ns, t_ns, names, effort=run.tau[k])
            bag.joint_state(topics["true_joint_torque"], t_ns, t_ns, names, effort=tau_j[k])
            bag.float_array(topics["true_contact"], t_ns, run.contact[k])
        return dict(bag.counts)


def read_arm_bag(path, system: str = "arm"):
    """(run, metadata) of an ``fto-simulate --urdf`` bag: an :class:`ArmRun` with a row per
    message of the stream that was recorded (lost ones absent) and the truth at its instant,
    plus ``run.stamp_ns`` (the header stamps), ``run.effort`` (what the stream's effort
    carried), ``run.tau_j`` and ``run.index`` (the sample number k of each row). Bags without
    the newer truth topics (the committed arm7 bags) read with tau = the stream's effort."""
    with BagReader(path) as bag:
        meta = json.loads(bag.custom_data.get(METADATA_KEY, "{}"))
        have = set(bag.topics)
        topics = topic_names(system) | meta.get("topics", {})
        wanted = [topics[k] for k in ("joint_states", "true_joint_states", "true_command",
                                      "true_joint_torque", "true_contact")]
        wanted = [w for w in wanted if w in have]
        rows: dict[str, list] = {w: [] for w in wanted}
        for topic, t_ns, msg in bag.messages(wanted):
            rows[topic].append((t_ns, msg))
    meas = rows[topics["joint_states"]]
    truth = {t_ns: k for k, (t_ns, _) in enumerate(rows[topics["true_joint_states"]])}
    idx = np.array([truth[t_ns] for t_ns, _ in meas], dtype=int)

    def field(topic, name, fallback=None):
        got = rows.get(topic)
        if not got:
            return fallback
        return np.array([getattr(m, name) for _, m in got])[idx]

    effort = np.array([m.effort for _, m in meas])
    true_t = np.array([t for t, _ in rows[topics["true_joint_states"]]])[idx] / 1e9
    tau = field(topics["true_command"], "effort", effort)
    tau_j = field(topics["true_joint_torque"], "effort")
    names = tuple(meas[0][1].name) if meas else ()
    joints = meta.get("driven", meta.get("joints", list(names)))
    run = ArmRun(t=true_t, q=field(topics["true_joint_states"], "position"),
                 v=field(topics["true_joint_states"], "velocity"),
                 q_measured=np.array([m.position for _, m in meas]), tau=tau,
                 tau_ext=field(topics["true_joint_states"], "effort"),
                 contact=np.array([m.data for _, m in rows[topics["true_contact"]]])[idx],
                 names=names, driven=np.array([names.index(j) for j in joints if j in names]),
                 stamp_ns=np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                                    for _, m in meas], dtype=np.int64),
                 effort=effort, tau_j=tau_j, index=idx)
    return run, meta
