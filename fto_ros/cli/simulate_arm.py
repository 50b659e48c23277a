"""``fto-simulate --urdf``: an arm from its URDF, simulated and recorded as a rosbag2 bag.

Usage::

    fto-simulate --urdf FILE --out BAG [--joints J1,J2,...] [--lock NAME=POSITION ...]
                 [--contact LINK,T,DURATION,FX,FY,FZ[,RISE] ...] [--duration S] [--rate HZ]
                 [--noise RAD] [--resolution RAD] [--seed N] [--system NAME] [--overwrite]

The model (fto_ros.models.arm): Pinocchio's forward dynamics, RK4 at 4 kHz, the URDF's
friction, a PD plus gravity compensation from the encoder, encoder noise and quantisation,
contact forces on named links. Topics (``SYS`` = ``--system``, default ``arm``), one message
of each per sample at its time:

- ``/SYS/joint_states`` (sensor_msgs/JointState, every joint by name): position = the
  encoder, effort = the torque commanded at that sample (held until the next one);
- ``/SYS/true_joint_states`` (JointState): the true position and velocity, and in effort the
  true external joint torque J^T F;
- ``/SYS/true_contact`` (std_msgs/Float64MultiArray): [active (0/1), fx, fy, fz];
- ``/clock``.

The settings (URDF path and its SHA-256, joints, contacts, noise, controller, seed) are
stored as JSON in metadata.yaml ``custom_data`` under ``fto_ros.simulation``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import __version__
from ..bag import BagError, BagWriter
from ..core.errors import ConfigError
from ..models.arm import ArmSettings, Contact, simulate_arm
from ..models.simulate import to_ns
from ..arm.model import load_model
from ..core.command_line import guarded, non_negative_float, one_line, positive_float

PROG = "fto-simulate"
METADATA_KEY = "fto_ros.simulation"


def _contact(text: str) -> Contact:
    parts = text.split(",")
    if len(parts) not in (6, 7):
        raise argparse.ArgumentTypeError(f"expected LINK,T,DURATION,FX,FY,FZ[,RISE], got {text!r}")
    try:
        nums = [float(p) for p in parts[1:]]
    except ValueError:
        raise argparse.ArgumentTypeError(f"T, DURATION, the force and RISE must be numbers, "
                                         f"got {text!r}") from None
    if not all(math.isfinite(x) for x in nums) or nums[1] <= 0 or (len(nums) == 6 and nums[5] < 0):
        raise argparse.ArgumentTypeError(f"need finite numbers, DURATION > 0, RISE >= 0: {text!r}")
    return Contact(parts[0].strip(), nums[0], nums[1], tuple(nums[2:5]),
                   nums[5] if len(nums) == 6 else 0.0)


def _lock(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        x = float(value)
    except ValueError:
        x = math.nan
    if not sep or not name or not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"expected NAME=POSITION, got {text!r}")
    return name, x


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"{PROG} --urdf", description="Simulate an arm from its "
                                "URDF and record a rosbag2 (MCAP) bag (docs/replay.md).")
    p.add_argument("--urdf", required=True, metavar="FILE", help="the arm's URDF")
    p.add_argument("--out", required=True, metavar="BAG", help="output bag directory")
    p.add_argument("--joints", metavar="J1,J2,...",
                   help="the joints that move (default: every movable joint of the URDF)")
    p.add_argument("--lock", action="append", default=[], type=_lock, metavar="NAME=POSITION",
                   help="a joint held at a position (the joints neither moving nor locked are "
                        "refused); repeatable")
    p.add_argument("--contact", action="append", default=[], type=_contact,
                   metavar="LINK,T,DURATION,FX,FY,FZ[,RISE]",
                   help="a force (N, world axes) on the origin of LINK's frame from T for "
                        "DURATION s, ramped over RISE s at both ends (default 0: a step); "
                        "repeatable")
    p.add_argument("--duration", type=positive_float, default=10.0, metavar="S")
    p.add_argument("--rate", type=positive_float, default=1000.0, metavar="HZ",
                   help="sample and control rate (default 1000)")
    p.add_argument("--noise", type=non_negative_float, default=1e-5, metavar="RAD",
                   help="encoder noise standard deviation (default 1e-5)")
    p.add_argument("--resolution", type=non_negative_float, default=2.0 ** -18, metavar="RAD",
                   help="encoder quantisation step (default 2^-18; 0: none)")
    p.add_argument("--seed", type=int, default=0, metavar="N")
    p.add_argument("--system", default="arm", metavar="NAME", help="topic namespace")
    p.add_argument("--overwrite", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``fto-simulate --urdf``; returns the exit code (argparse errors exit with 2)."""
    return guarded(PROG, _run, build_parser().parse_args(argv))


def _run(args) -> int:
    out = Path(args.out)
    if (out.exists() or out.is_symlink()) and not args.overwrite:
        print(f"{PROG}: error: {out}: output exists already (use --overwrite)", file=sys.stderr)
        return 1
    if args.duration * args.rate > 5e6:
        print(f"{PROG}: error: --duration x --rate is more than 5e6 samples", file=sys.stderr)
        return 2
    joints = None if args.joints is None else [j.strip() for j in args.joints.split(",")]
    started = time.perf_counter()
    try:
        model = load_model(joints, urdf=args.urdf, locked_joints=dict(args.lock))
        settings = ArmSettings(duration=args.duration, rate=args.rate, noise=args.noise,
                               resolution=args.resolution, seed=args.seed,
                               contacts=list(args.contact))
        if model.n != len(settings.q0):
            settings.q0 = (0.0,) * model.n
            settings.amplitude, settings.period = (0.3,) * model.n, (4.0,) * model.n
        run = simulate_arm(model, settings)
    except (ConfigError, ValueError) as err:
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 2
    sim_time = time.perf_counter() - started
    sysn = args.system
    topics = {"joint_states": f"/{sysn}/joint_states",
              "true_joint_states": f"/{sysn}/true_joint_states",
              "true_contact": f"/{sysn}/true_contact", "clock": "/clock"}
    meta = {
        "fto_ros_version": __version__, "model": "urdf_arm",
        "urdf": str(args.urdf), "urdf_sha256": hashlib.sha256(Path(args.urdf).read_bytes()).hexdigest(),
        "joints": list(model.joints), "locked_joints": dict(args.lock),
        "friction": {"viscous": model.viscous.tolist(), "coulomb": model.coulomb.tolist(),
                     "width": model.friction_width},
        "settings": {k: v for k, v in asdict(settings).items() if k != "contacts"},
        "contacts": [asdict(c) for c in settings.contacts],
        "integrator": {"method": "RK4", "step": 1.0 / (args.rate * settings.substeps),
                       "torque": "held over each sample period"},
        "topics": topics,
        "log_time": "sample time, round(t * 1e9) ns, t = 0 at the start",
    }
    names = list(model.joints)
    try:
        with BagWriter(out, overwrite=args.overwrite,
                       custom_data={METADATA_KEY: json.dumps(meta, sort_keys=True)}) as bag:
            for k, t in enumerate(run.t):
                t_ns = to_ns(t)
                bag.clock(t_ns)
                bag.joint_state(topics["joint_states"], t_ns, t_ns, names,
                                position=run.q_measured[k], effort=run.tau[k])
                bag.joint_state(topics["true_joint_states"], t_ns, t_ns, names,
                                position=run.q[k], velocity=run.v[k], effort=run.tau_ext[k])
                bag.float_array(topics["true_contact"], t_ns, run.contact[k])
            counts = dict(bag.counts)
    except BagError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 1
    size = sum(p.stat().st_size for p in out.iterdir() if p.is_file())
    peak = np.abs(run.tau_ext).max(axis=0)
    print(f"{PROG}: wrote {out} ({size / 1024:.0f} KiB, {sum(counts.values())} messages, "
          f"{len(names)} joints, {len(settings.contacts)} contact(s), peak |tau_ext| per joint "
          f"{np.round(peak, 2).tolist()} Nm) in {time.perf_counter() - started:.1f} s "
          f"(simulation {sim_time:.1f} s)")
    return 0


def read_arm_bag(path, system: str = "arm"):
    """The ArmRun an ``fto-simulate --urdf`` bag holds (its topics as written above) and the
    bag's simulation settings."""
    from ..bag import BagReader
    from ..models.arm import ArmRun
    topics = {f"/{system}/joint_states": [], f"/{system}/true_joint_states": [],
              f"/{system}/true_contact": []}
    with BagReader(path) as bag:
        meta = json.loads(bag.custom_data.get(METADATA_KEY, "{}"))
        for topic, t_ns, msg in bag.messages(list(topics)):
            topics[topic].append((t_ns, msg))
    meas, truth, contact = (topics[k] for k in topics)
    run = ArmRun(t=np.array([t for t, _ in meas]) / 1e9,
                 q=np.array([m.position for _, m in truth]),
                 v=np.array([m.velocity for _, m in truth]),
                 q_measured=np.array([m.position for _, m in meas]),
                 tau=np.array([m.effort for _, m in meas]),
                 tau_ext=np.array([m.effort for _, m in truth]),
                 contact=np.array([m.data for _, m in contact]))
    return run, meta
