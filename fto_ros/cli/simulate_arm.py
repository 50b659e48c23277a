"""``fto-simulate --urdf``: an arm from its URDF, simulated and recorded as a rosbag2 bag.

Usage::

    fto-simulate --urdf FILE --out BAG [--joints J1,J2,...] [--lock NAME=POSITION ...]
                 [--contact LINK,T,DURATION,FX,FY,FZ[,RISE] ...] [--duration S] [--rate HZ]
                 [--substeps N] [--noise RAD] [--resolution RAD] [--seed N]
                 [--q0 LIST] [--amplitude LIST] [--period LIST] [--gripper-period S]
                 [--jitter US] [--stamp-noise US] [--loss P] [--loss-burst N]
                 [--model-error E] [--model-seed N] [--friction VLO,VHI,CLO,CHI]
                 [--payload FRAME,MASS[,CX,CY,CZ[,IXX,IYY,IZZ]]]
                 [--effort KIND] [--torque-noise NM] [--current-noise A] [--kt LIST] [--gear LIST]
                 [--topic NAME] [--system NAME] [--overwrite]

The model (fto_ros.models.arm): the true arm's dynamics (RK4, 4 steps per sample), a PD plus
gravity compensation on the nominal URDF from the encoder, encoder noise and quantisation,
a gripper, contact forces on named links. Joints: ``--joints`` (default: the arm's trunk,
the movable joints on every path to a leaf) are driven; the other movable joints off the
trunk are gripper fingers, moving on the gripper's trajectory (``--gripper-period``); a
``<mimic>`` joint follows its parent finger exactly; ``--lock`` holds joints still.

A real arm's stream: ``--jitter`` (the actual sampling instants), ``--stamp-noise`` (the
header stamps' error), ``--loss``/``--loss-burst`` (messages not recorded; the controller
runs on), ``--effort`` (what JointState.effort carries: fto_ros.models.arm_stream.effort).
An arm that differs from its URDF: ``--model-error`` (the simulated links' masses, inertias
and centres of mass; fto_ros.models.arm_urdf.perturbed) and ``--friction`` (viscous b and
Coulomb f_c per driven joint, uniform in the ranges, instead of the URDF's), both drawn
with ``--model-seed``; ``--payload`` (a load the arm carries, as after a grasp); the
estimators get the URDF as it is. The bag's topics:
:mod:`fto_ros.cli.arm_bag`. Everything that was drawn (per-link scales, friction, lost
count) is stored as JSON in metadata.yaml ``custom_data`` under ``fto_ros.simulation``.
"""
from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import __version__
from ..bag import BagError
from ..core.command_line import guarded, non_negative_float, one_line, positive_float, \
    positive_int
from ..core.errors import ConfigError, FtoRosError
from ..models import arm_stream
from ..models.arm import ArmSettings, Contact, Gripper, simulate_arm
from ..models.arm_urdf import MOVABLE, perturbed, trunk, urdf_joints, without_mimic
from ..arm.model import load_model
from .arm_bag import METADATA_KEY, read_arm_bag, topic_names, write_arm_bag

__all__ = ["METADATA_KEY", "build_parser", "main", "read_arm_bag"]

PROG = "fto-simulate"


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line (exit 2)."""

    def error(self, message):
        self.exit(2, f"{PROG}: error: {' '.join(message.split())}\n")


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


def _numbers(text: str) -> list[float]:
    try:
        out = [float(x) for x in text.split(",")]
    except ValueError:
        out = [math.nan]
    if not all(math.isfinite(x) for x in out):
        raise argparse.ArgumentTypeError(f"expected finite numbers separated by commas, got "
                                         f"{text!r}")
    return out


def _positive_numbers(text: str) -> list[float]:
    out = _numbers(text)
    if not all(x > 0 for x in out):
        raise argparse.ArgumentTypeError(f"every value must be > 0, got {text!r}")
    return out


def _friction(text: str) -> tuple[float, float, float, float]:
    out = _numbers(text)
    if len(out) != 4 or not (0 <= out[0] <= out[1] and 0 <= out[2] <= out[3]):
        raise argparse.ArgumentTypeError(f"expected VISC_LO,VISC_HI,COUL_LO,COUL_HI with "
                                         f"0 <= LO <= HI, got {text!r}")
    return tuple(out)


def _payload(text: str) -> tuple:
    """FRAME,MASS[,CX,CY,CZ[,IXX,IYY,IZZ]]: a payload the simulated arm carries."""
    frame, _, rest = text.partition(",")
    nums = _numbers(rest) if rest else []
    if not frame.strip() or len(nums) not in (1, 4, 7) or nums[0] <= 0 or \
            any(x < 0 for x in nums[4:]):
        raise argparse.ArgumentTypeError(f"expected FRAME,MASS[,CX,CY,CZ[,IXX,IYY,IZZ]] with "
                                         f"MASS > 0 and moments >= 0, got {text!r}")
    nums = nums + [0.0] * (7 - len(nums))
    return frame.strip(), nums[0], tuple(nums[1:4]), tuple(nums[4:7])


def _probability(text: str) -> float:
    x = non_negative_float(text)
    if x >= 1:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1), got {text!r}")
    return x


def _model_error(text: str) -> float:
    x = non_negative_float(text)
    if x >= 1:
        raise argparse.ArgumentTypeError(f"must be a relative error in [0, 1), got {text!r}")
    return x


def _topic(text: str) -> str:
    name = text if text.startswith("/") else "/" + text
    parts = name[1:].split("/")
    if not all(p and (p[0].isalpha() or p[0] == "_") and all(c.isalnum() or c == "_" for c in p)
               for p in parts):
        raise argparse.ArgumentTypeError(f"not a ROS topic name: {text!r}")
    return name


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=f"{PROG} --urdf", description="Simulate an arm from its URDF and record a "
                "rosbag2 (MCAP) bag (docs/replay.md, docs/arm_class.md).")
    a = p.add_argument
    a("--urdf", required=True, metavar="FILE", help="the arm's URDF")
    a("--out", required=True, metavar="BAG", help="output bag directory")
    a("--joints", metavar="J1,J2,...", help="the joints the controller drives (default: the "
      "arm's trunk; the movable joints off it are gripper fingers)")
    a("--lock", action="append", default=[], type=_lock, metavar="NAME=POSITION",
      help="a joint held at a position; repeatable")
    a("--contact", action="append", default=[], type=_contact,
      metavar="LINK,T,DURATION,FX,FY,FZ[,RISE]",
      help="a force (N, world axes) on the origin of LINK's frame from T for DURATION s, "
           "ramped over RISE s at both ends (default 0: a step); repeatable")
    a("--duration", type=positive_float, default=10.0, metavar="S")
    a("--rate", type=positive_float, default=1000.0, metavar="HZ",
      help="sample and control rate (default 1000)")
    a("--substeps", type=positive_int, default=4, metavar="N",
      help="RK4 steps per sample period (default 4)")
    a("--noise", type=non_negative_float, default=1e-5, metavar="RAD",
      help="encoder noise standard deviation (default 1e-5)")
    a("--resolution", type=non_negative_float, default=2.0 ** -18, metavar="RAD",
      help="encoder quantisation step (default 2^-18; 0: none)")
    a("--seed", type=int, default=0, metavar="N",
      help="encoder noise, jitter, stamp noise, losses, sensor noise")
    a("--q0", type=_numbers, metavar="LIST", help="start pose per driven joint (rad)")
    a("--amplitude", type=_numbers, metavar="LIST", help="A per driven joint: q_d = q0 + "
      "A (1 - cos(2 pi t / P)) / 2")
    a("--period", type=_positive_numbers, metavar="LIST", help="P per driven joint (s)")
    a("--gripper-period", type=non_negative_float, default=0.0, metavar="S",
      help="one opening and closing of the fingers (default 0: still)")
    a("--jitter", type=non_negative_float, default=0.0, metavar="US",
      help="the actual sampling instants k/rate + uniform(-US, US) microseconds (default 0)")
    a("--stamp-noise", type=non_negative_float, default=0.0, metavar="US",
      help="header stamp error relative to the actual instant, uniform(-US, US) us (default 0)")
    a("--loss", type=_probability, default=0.0, metavar="P",
      help="probability that a stream message is not recorded (default 0)")
    a("--loss-burst", type=positive_int, default=1, metavar="N",
      help="lost messages come in runs of 1..N (default 1)")
    a("--model-error", type=_model_error, default=0.0, metavar="E",
      help="the simulated links' masses and inertias differ from the URDF's by up to E "
           "(relative), centres of mass by up to E x 0.1 m (default 0)")
    a("--model-seed", type=int, default=0, metavar="N", help="draws the model error and friction")
    a("--friction", type=_friction, metavar="VLO,VHI,CLO,CHI",
      help="viscous (N m s/rad) and Coulomb (N m) friction per driven joint, uniform in these "
           "ranges (default: the URDF's)")
    a("--payload", type=_payload, metavar="FRAME,MASS[,CX,CY,CZ[,IXX,IYY,IZZ]]",
      help="the simulated arm carries a payload the URDF lacks (as after a grasp): mass (kg), "
           "centre of mass (m) and principal moments about it (kg m^2), frame axes")
    a("--effort", choices=arm_stream.EFFORTS, default="commanded",
      help="what JointState.effort carries (default: commanded)")
    a("--torque-noise", type=non_negative_float, default=0.0, metavar="NM",
      help="--effort measured: the torque sensor's noise (default 0)")
    a("--current-noise", type=non_negative_float, default=0.0, metavar="A",
      help="--effort current: the current's noise (default 0)")
    a("--kt", type=_positive_numbers, default=[0.1], metavar="LIST",
      help="--effort current: torque constant per driven joint, N m/A (default 0.1)")
    a("--gear", type=_positive_numbers, default=[100.0], metavar="LIST",
      help="--effort current: gear ratio per driven joint (default 100)")
    a("--topic", type=_topic, metavar="NAME",
      help="the JointState stream's topic (default /SYSTEM/joint_states)")
    a("--system", default="arm", metavar="NAME", help="topic namespace")
    a("--overwrite", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``fto-simulate --urdf``; returns the exit code (argparse errors exit with 2)."""
    return guarded(PROG, _run, build_parser().parse_args(argv))


def _fail(message: str, code: int) -> int:
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return code


def _joint_roles(text: str, args):
    """(driven, fingers {name: (lo, hi)}, mimic {name: (parent, m, o)}, locks, joints dict)."""
    joints = urdf_joints(text)
    locks = dict(args.lock)
    movable = [j for j in joints.values() if j.kind in MOVABLE]
    if args.joints is None:
        driven = [j for j in trunk(joints) if j not in locks]
    else:
        driven = [j.strip() for j in args.joints.split(",")]
    for j in driven:
        if j in joints and joints[j].mimic:
            raise ConfigError("joints", f"{j} is a mimic joint of {joints[j].mimic[0]}: "
                                              f"list its parent")
    arm = set(trunk(joints))
    fingers = {j.name: (j.lower, j.upper) for j in movable if j.name not in driven
               and j.name not in locks and not j.mimic and j.name not in arm}
    mimic = {}
    for j in movable:
        if not j.mimic or j.name in locks:
            continue
        parent, mult, off = j.mimic
        if parent in locks:
            locks[j.name] = mult * locks[parent] + off
        elif parent in fingers:
            mimic[j.name] = j.mimic
        else:
            raise ConfigError("joints", f"mimic joint {j.name} follows {parent}, which "
                                              f"is driven: the simulator moves mimic joints of "
                                              f"gripper fingers only")
    return driven, fingers, mimic, locks, joints


def _trajectory(args, driven, joints) -> dict:
    """q0, amplitude, period per driven joint, checked against the URDF's limits."""
    n = len(driven)
    base = ArmSettings()
    q0 = args.q0 or (list(base.q0) if n == len(base.q0) else [0.0] * n)
    amp = args.amplitude or (list(base.amplitude) if n == len(base.amplitude) else [0.3] * n)
    period = args.period or (list(base.period) if n == len(base.period) else [4.0] * n)
    for name, vals in (("q0", q0), ("amplitude", amp), ("period", period)):
        if len(vals) not in (1, n):
            raise ConfigError(name, f"one value or one per driven joint ({n}), got {len(vals)}")
    q0, amp = np.broadcast_to(q0, n), np.broadcast_to(amp, n)
    for j, a, b in zip(driven, q0, q0 + amp):
        lim = joints.get(j)
        if lim is not None and not (lim.lower <= min(a, b) and max(a, b) <= lim.upper):
            raise ConfigError("q0", f"joint {j} would move over [{min(a, b):g}, {max(a, b):g}], "
                                    f"outside its limits [{lim.lower:g}, {lim.upper:g}]")
    return {"q0": tuple(q0), "amplitude": tuple(amp), "period": tuple(np.broadcast_to(period, n))}


def _per_driven(values, n: int, name: str) -> np.ndarray:
    if len(values) not in (1, n):
        raise ConfigError(name, f"one value or one per driven joint ({n}), got {len(values)}")
    return np.broadcast_to(np.asarray(values, dtype=float), (n,)).copy()


def _run(args) -> int:
    out = Path(args.out)
    if (out.exists() or out.is_symlink()) and not args.overwrite:
        return _fail(f"{out}: output exists already (use --overwrite)", 1)
    if args.duration * args.rate > 5e6:
        return _fail("--duration x --rate is more than 5e6 samples", 2)
    h = 1.0 / args.rate
    if (args.jitter + args.stamp_noise) * 1e-6 >= 0.5 * h:
        return _fail(f"--jitter + --stamp-noise must stay below half the period "
                     f"({0.5e6 * h:g} us): the stamps would not increase", 2)
    started = time.perf_counter()
    try:
        load_model(None, urdf=args.urdf, locked_joints=dict(args.lock))   # the file's checks
        text = Path(args.urdf).read_text(encoding="utf-8")
        driven, fingers, mimic, locks, joints = _joint_roles(text, args)
        moving = list(driven) + [j for j in joints if j in fingers or j in mimic]
        nominal = load_model(moving, robot_description=without_mimic(text), locked_joints=locks)
        A = [moving.index(j) for j in driven]
        friction, viscous, coulomb = None, None, None
        if args.friction is not None:
            rng = np.random.default_rng([args.model_seed, 7002])
            vlo, vhi, clo, chi = args.friction
            viscous, coulomb = np.zeros(len(moving)), np.zeros(len(moving))
            viscous[A] = rng.uniform(vlo, vhi, len(A))
            coulomb[A] = rng.uniform(clo, chi, len(A))
        true_text, links = perturbed(text, args.model_error, args.model_seed)
        model = load_model(moving, robot_description=without_mimic(true_text),
                           locked_joints=locks, viscous_friction=viscous,
                           coulomb_friction=coulomb)
        if args.payload is not None:
            frame, mass, com, moments = args.payload
            model.set_payload(frame, mass, com, np.diag(moments))
        kt = _per_driven(args.kt, len(A), "kt")
        gear = _per_driven(args.gear, len(A), "gear")
        settings = ArmSettings(duration=args.duration, rate=args.rate, substeps=args.substeps,
                               noise=args.noise, resolution=args.resolution, seed=args.seed,
                               contacts=list(args.contact), jitter=args.jitter * 1e-6,
                               gripper_period=args.gripper_period,
                               **_trajectory(args, driven, joints))
        run = simulate_arm(model, settings, driven=driven, gripper=Gripper(fingers, mimic),
                           nominal=nominal)
        N = run.t.size
        stamps = arm_stream.header_stamps(run.t, args.stamp_noise * 1e-6, args.seed)
        lost = arm_stream.lost_messages(N, args.loss, args.loss_burst, args.seed)
        effort = np.zeros_like(run.tau)
        effort[:, A] = arm_stream.effort(args.effort, run.tau[:, A], run.gravity[:, A],
                                         run.friction[:, A], args.seed, args.torque_noise,
                                         args.current_noise, kt, gear)
    except ConfigError as err:
        return _fail(str(err), 2)
    except FtoRosError as err:          # the simulation diverged
        return _fail(str(err), 1)
    sim_time = time.perf_counter() - started
    topics = topic_names(args.system, args.topic)
    meta = {
        "fto_ros_version": __version__, "model": "urdf_arm", "samples": int(N),
        "urdf": str(args.urdf), "urdf_sha256": hashlib.sha256(Path(args.urdf).read_bytes()).hexdigest(),
        "joints": list(model.joints), "driven": list(driven), "locked_joints": locks,
        "gripper": {"fingers": {k: list(v) for k, v in fingers.items()},
                    "mimic": {k: list(v) for k, v in mimic.items()},
                    "period": args.gripper_period},
        "friction": {"viscous": model.viscous.tolist(), "coulomb": model.coulomb.tolist(),
                     "width": model.friction_width, "drawn": args.friction},
        "model_error": {"error": args.model_error, "seed": args.model_seed, "links": links},
        "payload": None if args.payload is None else
        {"frame": args.payload[0], "mass": args.payload[1], "com": list(args.payload[2]),
         "moments": list(args.payload[3])},
        "stream": {"topic": topics["joint_states"], "jitter_us": args.jitter,
                   "stamp_noise_us": args.stamp_noise, "loss": args.loss,
                   "loss_burst": args.loss_burst, "lost": int(lost.sum()),
                   "effort": args.effort, "torque_noise": args.torque_noise,
                   "current_noise": args.current_noise, "kt": kt.tolist(),
                   "gear": gear.tolist()},
        "settings": {k: v for k, v in asdict(settings).items() if k != "contacts"},
        "contacts": [asdict(c) for c in settings.contacts],
        "integrator": {"method": "RK4", "max_step": h / settings.substeps,
                       "torque": "held over each control interval", "cut_at": "contact switches"},
        "topics": topics,
        "log_time": "the sample's actual instant, round(t * 1e9) ns, t = 0 at the start",
    }
    try:
        counts = write_arm_bag(out, run, topics, stamps, lost, effort, meta, args.overwrite)
    except (BagError, FtoRosError) as err:
        return _fail(str(err), 1)
    size = sum(p.stat().st_size for p in out.iterdir() if p.is_file())
    peak = np.abs(run.tau_ext[:, A]).max(axis=0)
    print(f"{PROG}: wrote {out} ({size / 1024:.0f} KiB, {sum(counts.values())} messages, "
          f"{len(moving)} joints ({len(driven)} driven), {len(settings.contacts)} contact(s), "
          f"{int(lost.sum())} lost, peak |tau_ext| per driven joint "
          f"{np.round(peak, 2).tolist()} Nm) in {time.perf_counter() - started:.1f} s "
          f"(simulation {sim_time:.1f} s)")
    return 0
