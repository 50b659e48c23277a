"""``fto-simulate``: simulate a plant from ``fto_ros.models`` and record a rosbag2 (MCAP) bag.

Usage::

    fto-simulate MODEL --out BAG [--duration S] [--rate HZ] [--noise SIGMA]
                 [--uncertainty] [--seed N] [--state-jump T,STATE,DELTA ...]
                 [--sample-times FILE | --sparse-min S --sparse-max S] [--overwrite]
    fto-simulate --params FILE [--params FILE ...] [--set NAME=VALUE] --out BAG [...]
    fto-simulate --urdf FILE --out BAG [--joints ...] [--contact ...] [...]

The second form simulates a user's plant block with the ``simulation.*`` parameters of the
params files (:mod:`fto_ros.cli.simulate_plant`); ``--duration``, ``--rate``, ``--noise``
and ``--seed`` override them when given. The third simulates an arm from its URDF
(:mod:`fto_ros.cli.simulate_arm`).

Topics (``SYS`` = the model name, e.g. ``dc_motor``):

- ``/SYS/input`` (Float64MultiArray): the held input ``u_k``, at the base rate.
- ``/SYS/measured_output`` (Float64MultiArray): measured ``y`` (with noise), at
  the measurement instants.
- ``/SYS/joint_states`` (JointState): the same measurement as joint positions
  (header stamp = sample time, velocity and effort empty), for models whose
  outputs are joint positions.
- ``/SYS/true_state`` (Float64MultiArray): the true state, at the base rate
  *and* at every measurement instant (so ground truth exists wherever an
  estimate can be produced).
- ``/SYS/true_unknown_input`` (Float64MultiArray): the true unknown input zeta(t), at the
  instants of ``true_state``, for models with one (``UnknownInputModelSpec``: the
  ``fld_example*`` plants, ``dc_motor_load``).
- ``/clock`` (rosgraph_msgs/Clock): at every instant where anything is published.

``SYS`` is the model's ``system_name`` when it has one (``dc_motor_load`` records on the
``/dc_motor`` topics).  ``--output-disturbance`` adds the model's deterministic output
disturbance (``fld_example1``: the paper's noise 0.1 sin(1037 |cos(687 t)|)).

The log time of every message is its sample time, ``round(t * 1e9)`` ns with
``t = 0`` at the start of the simulation (MCAP and rosbag2 accept 0).  Within
one instant the order is clock, input, true_state, measured_output, joint_states.

The simulation settings (model, parameters, initial state, input profile,
noise, uncertainty, sampling, seed, integrator) are stored as JSON in the bag's
metadata.yaml ``custom_data`` under the key ``fto_ros.simulation``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import __version__
from ..bag import BagError, BagWriter
from ..core.output_dir import OutputError, OutputExists, check_output
from ..models import MODELS
from ..core.command_line import non_negative_float, positive_float
from ..models.simulate import quantize_ns, simulate, sparse_instants, to_ns, uniform_grid
from ..core.errors import BadArgument, CommandLineError

PROG = "fto-simulate"
#: metadata.yaml custom_data key holding the simulation settings (JSON)
METADATA_KEY = "fto_ros.simulation"
RTOL, ATOL, METHOD = 1e-11, 1e-12, "DOP853"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``fto-simulate``."""
    models = ", ".join(f"{name} ({spec.description})" for name, spec in sorted(MODELS.items()))
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Simulate a plant and record a rosbag2 (MCAP) bag with its measured "
                    "output, input, joint_states, ground truth and /clock.",
        epilog=f"models: {models}")
    parser.add_argument("model", metavar="MODEL", nargs="?", help=f"plant to simulate; one of: "
                        f"{', '.join(sorted(MODELS))} (or --params)")
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="params files with a plant block and simulation.* parameters "
                             "(instead of MODEL; several merge in order)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="with --params: override one parameter, e.g. simulation.seed=3")
    parser.add_argument("--out", required=True, metavar="BAG",
                        help="output bag directory (must not exist unless --overwrite)")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="simulated time in seconds (default 10)")
    parser.add_argument("--rate", type=positive_float, default=None, metavar="HZ",
                        help="base rate of input, ground truth and clock, and of the "
                             "measurements unless sparse (default 1000)")
    parser.add_argument("--noise", type=non_negative_float, default=None, metavar="SIGMA",
                        help="std. deviation of Gaussian measurement noise on every output "
                             "(default 0: exact measurements)")
    parser.add_argument("--uncertainty", action="store_true",
                        help="add the model's default process uncertainty delta1(t)")
    parser.add_argument("--seed", type=int, default=None, metavar="N",
                        help="seed of the noise and of the sparse sampling (default 0)")
    parser.add_argument("--sample-times", metavar="FILE",
                        help="measurement instants in seconds (whitespace/comma separated, "
                             "'#' comments), instead of the base rate")
    parser.add_argument("--sparse-min", type=positive_float, metavar="S",
                        help="irregular measurements: smallest gap between instants")
    parser.add_argument("--sparse-max", type=positive_float, metavar="S",
                        help="irregular measurements: largest gap between instants")
    parser.add_argument("--output-disturbance", action="store_true",
                        help="add the model's deterministic output disturbance (models that "
                             "define one, e.g. fld_example1)")
    parser.add_argument("--state-jump", action="append", default=[], metavar="T,STATE,DELTA",
                        type=_state_jump,
                        help="at time T (s) the state STATE (index or name) jumps by DELTA, "
                             "e.g. 5.0,q_dot,4 (a collision); repeatable")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace BAG if it exists, only if it is an empty folder or a bag "
                             "fto_ros wrote (never a file, a symlink, a device or another folder)")
    return parser


def _state_jump(text: str) -> tuple[float, str, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise CommandLineError(f"expected T,STATE,DELTA, got {text!r}")
    try:
        t, delta = float(parts[0]), float(parts[2])
    except ValueError:
        raise CommandLineError(f"T and DELTA must be numbers, got {text!r}") from None
    if not (math.isfinite(t) and math.isfinite(delta)):
        raise CommandLineError(f"T and DELTA must be finite, got {text!r}")
    return t, parts[1].strip(), delta


def _jumps(args, parser, spec) -> list[tuple[float, int, float]]:
    """--state-jump values with the state as an index (a name is looked up)."""
    names = list(getattr(spec, "state_names", None) or [])
    out = []
    for t, state, delta in args.state_jump:
        if state.isdigit():
            i = int(state)
        elif state in names:
            i = names.index(state)
        else:
            parser.error(f"--state-jump: unknown state {state!r} (states: "
                         f"{', '.join(names) or 'by index 0..' + str(spec.n - 1)})")
        if not (0 <= i < spec.n) or not (0.0 < t <= args.duration):
            parser.error(f"--state-jump {t},{state},{delta}: needs 0 < T <= --duration and a "
                         f"state index in 0..{spec.n - 1}")
        out.append((t, i, delta))
    return out


def _plant_model(args):
    """(spec, simulation settings, plant) of the --params files (ConfigError for bad ones)."""
    from ..runner.params_file import parse_override
    from .simulate_plant import load, plant_spec
    overrides = dict(parse_override(text) for text in args.set)
    plant, sim = load(args.params, overrides)
    return plant_spec(plant, sim, ", ".join(args.params)), sim, plant


def read_sample_times(path: str) -> np.ndarray:
    """Parse a file of instants in seconds (whitespace/comma separated, '#' comments)."""
    text = Path(path).read_text()
    tokens = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].replace(",", " ")
        tokens.extend(line.split())
    try:
        return np.array([float(tok) for tok in tokens], dtype=float)
    except ValueError as err:
        raise BadArgument(f"{path}: not a list of numbers ({err})") from None


def _measurement_instants(args, parser, base: np.ndarray,
                          rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """Measurement instants and their description for the metadata."""
    sparse = args.sparse_min is not None or args.sparse_max is not None
    if sparse and args.sample_times:
        parser.error("--sample-times and --sparse-min/--sparse-max are mutually exclusive")
    if sparse:
        if args.sparse_min is None or args.sparse_max is None:
            parser.error("--sparse-min and --sparse-max must be given together")
        if args.sparse_min > args.sparse_max:
            parser.error(f"--sparse-min ({args.sparse_min}) must be <= --sparse-max "
                         f"({args.sparse_max})")
        t = sparse_instants(args.duration, args.sparse_min, args.sparse_max, rng)
        return t, {"mode": "sparse", "t_min": args.sparse_min, "t_max": args.sparse_max,
                   "description": "t_0 = 0, t_{j+1} - t_j ~ uniform[t_min, t_max] "
                                  "(integer ns), seeded"}
    if args.sample_times:
        try:
            t = read_sample_times(args.sample_times)
        except (OSError, ValueError) as err:
            parser.error(f"--sample-times: {err}")
        if t.size == 0:
            parser.error(f"--sample-times: {args.sample_times} holds no instants")
        t = quantize_ns(t)
        if np.any(np.diff(t) <= 0):
            parser.error(f"--sample-times: instants in {args.sample_times} must be strictly "
                         f"increasing (at nanosecond resolution)")
        if t[0] < 0 or t[-1] > base[-1]:
            parser.error(f"--sample-times: instants must lie in [0, {args.duration}] s, got "
                         f"[{t[0]}, {t[-1]}]")
        return t, {"mode": "file", "file": os.path.abspath(args.sample_times)}
    return base, {"mode": "uniform", "rate": args.rate}


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``fto-simulate``; returns the exit code (argparse errors exit with 2)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if any(a == "--urdf" or a.startswith("--urdf=") for a in argv):
        from .simulate_arm import main as arm_main       # an arm from its URDF
        return arm_main(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    defaults = dict(duration=10.0, rate=1000.0, noise=0.0, seed=0)
    if args.params:
        if args.model is not None:
            parser.error("give MODEL or --params, not both")
        try:
            spec, sim_cfg, plant = _plant_model(args)
        except ValueError as err:           # ConfigError: one line, bad parameters
            print(f"{PROG}: error: {' '.join(str(err).split())}", file=sys.stderr)
            return 2
        defaults.update(duration=sim_cfg["duration"], rate=sim_cfg["rate"], seed=sim_cfg["seed"],
                        noise=np.asarray(sim_cfg["noise"] or [0.0], dtype=float))
        if args.uncertainty or args.output_disturbance:
            parser.error("--uncertainty and --output-disturbance belong to the built-in models")
    else:
        if args.set:
            parser.error("--set needs --params")
        spec = MODELS.get(args.model) if args.model is not None else None
        if spec is None:
            parser.error(f"unknown model {args.model!r}; known models: "
                         f"{', '.join(sorted(MODELS))} (or give --params)")
    for key, value in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    if args.duration * args.rate > 5e7:
        parser.error(f"--duration x --rate = {args.duration * args.rate:.3g} samples is too many "
                     f"(limit 5e7)")
    if np.any(np.asarray(args.noise) > 0) and spec.p == 0:
        parser.error(f"model {spec.name} has no outputs to add noise to")
    disturbance = getattr(spec, "output_disturbance", None)
    if args.output_disturbance and disturbance is None:
        parser.error(f"model {spec.name} defines no output disturbance")
    if args.uncertainty and spec.uncertainty is None:
        parser.error(f"model {spec.name} defines no uncertainty")
    inputs = [*args.params, *([args.sample_times] if args.sample_times else [])]
    try:
        out = check_output(args.out, "bag", overwrite=args.overwrite, inputs=inputs)
    except OutputError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except OutputExists as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 1

    jumps = _jumps(args, parser, spec)
    noise_ss, sample_ss = np.random.SeedSequence(args.seed).spawn(2)
    noise_rng, sample_rng = np.random.default_rng(noise_ss), np.random.default_rng(sample_ss)
    base = uniform_grid(args.duration, args.rate)
    t_meas, sampling = _measurement_instants(args, parser, base, sample_rng)
    t_all = np.union1d(base, t_meas)

    started = time.perf_counter()
    f = spec.make_rhs(dict(spec.default_params))
    delta1 = spec.uncertainty if args.uncertainty else None
    try:
        sim = simulate(f, spec.default_x0, t_all, spec.default_input, t_input=base,
                       delta1=delta1, method=METHOD, rtol=RTOL, atol=ATOL, jumps=jumps)
    except ValueError as err:
        print(f"{PROG}: error: simulation failed: {err}", file=sys.stderr)
        return 1
    meas_idx = np.searchsorted(t_all, t_meas)
    y_true = np.array([np.atleast_1d(spec.output(x)) for x in sim.x[meas_idx]]) \
        .reshape(t_meas.size, spec.p)
    y = y_true + np.asarray(args.noise) * noise_rng.standard_normal(y_true.shape) \
        if np.any(np.asarray(args.noise) > 0) else y_true
    if args.output_disturbance:
        y = y + np.array([np.atleast_1d(disturbance(float(tk))) for tk in t_meas]).reshape(y.shape)
    zeta_fn = getattr(spec, "unknown_input", None)
    zeta = None if zeta_fn is None else \
        np.array([np.atleast_1d(zeta_fn(float(tk))) for tk in t_all], dtype=float)
    sim_time = time.perf_counter() - started

    sys_name = getattr(spec, "system", None) or spec.name
    topics = {
        "input": f"/{sys_name}/input",
        "measured_output": f"/{sys_name}/measured_output",
        "joint_states": f"/{sys_name}/joint_states",
        "true_state": f"/{sys_name}/true_state",
        "clock": "/clock",
    }
    if zeta is not None:
        topics["true_unknown_input"] = f"/{sys_name}/true_unknown_input"
    if spec.m == 0:
        del topics["input"]
    if not spec.joint_names:
        del topics["joint_states"]
    settings = {
        "fto_ros_version": __version__,
        "model": spec.name,
        "description": spec.description,
        "state_names": list(spec.state_names),
        "input_names": list(spec.input_names),
        "output_names": list(spec.output_names),
        "joint_names": list(spec.joint_names),
        "params": dict(spec.default_params),
        "x0": [float(v) for v in spec.default_x0],
        "t0": 0.0,
        "duration": args.duration,
        "base_rate": args.rate,
        "input_profile": spec.input_description,
        "input_hold": "zero-order hold at the base-rate instants" if not args.params or
                      sim_cfg["input_hold"] == "zoh" else "smooth: the plant saw u(t); the bag has "
                                                      "its samples at the base-rate instants",
        "measurement_sampling": sampling,
        "measurement_noise": {"type": "gaussian", "sigma": np.asarray(args.noise).tolist(),
                              "applies_to": list(spec.output_names)},
        "uncertainty": {"enabled": bool(args.uncertainty),
                        "description": spec.uncertainty_description if args.uncertainty
                        else "none"},
        "seed": args.seed,
        "state_jumps": [{"t": t, "state": spec.state_names[i] if i < len(spec.state_names)
                         else i, "delta": d} for t, i, d in jumps],
        "integrator": {"method": METHOD, "rtol": RTOL, "atol": ATOL,
                       "scheme": "piecewise between consecutive instants, input held exactly"},
        "topics": topics,
        "log_time": "sample time, round(t * 1e9) ns, t = 0 at the start",
    }
    if args.params:
        settings["params_files"] = [os.path.abspath(p) for p in args.params]
        settings["plant"] = {"states": plant.states, "inputs": plant.inputs,
                             "unknown_inputs": plant.unknown_inputs,
                             "constants": plant.constant_texts, "f": plant.f_texts,
                             "h": plant.h_texts}
    if zeta is not None:
        settings["unknown_input"] = {"names": list(spec.unknown_input_names),
                                     "description": spec.unknown_input_description}
    if disturbance is not None:
        settings["output_disturbance"] = {
            "enabled": bool(args.output_disturbance),
            "description": spec.output_disturbance_description if args.output_disturbance
            else "none"}

    is_input = np.zeros(t_all.size, dtype=bool)
    is_input[np.searchsorted(t_all, base)] = True
    u_at = sim.u
    is_meas = np.zeros(t_all.size, dtype=bool)
    is_meas[meas_idx] = True
    meas_row = np.full(t_all.size, -1)
    meas_row[meas_idx] = np.arange(t_meas.size)
    joints = list(spec.joint_names)

    try:
        with BagWriter(out, overwrite=args.overwrite, inputs=inputs,
                       custom_data={METADATA_KEY: json.dumps(settings, sort_keys=True)}) as bag:
            for i, t in enumerate(t_all):
                t_ns = to_ns(t)
                bag.clock(t_ns)
                if is_input[i] and spec.m:
                    bag.float_array(topics["input"], t_ns, u_at[i])
                bag.float_array(topics["true_state"], t_ns, sim.x[i])
                if zeta is not None:
                    bag.float_array(topics["true_unknown_input"], t_ns, zeta[i])
                if is_meas[i]:
                    yj = y[meas_row[i]]
                    bag.float_array(topics["measured_output"], t_ns, yj)
                    if joints:
                        bag.joint_state(topics["joint_states"], t_ns, t_ns, joints, position=yj)
            counts = dict(bag.counts)
    except OutputError as err:              # the output changed since it was checked
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except (BagError, OutputExists) as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 1
    total = time.perf_counter() - started
    size = sum(p.stat().st_size for p in out.iterdir() if p.is_file())
    listing = ", ".join(f"{name} {count}" for name, count in sorted(counts.items()))
    print(f"{PROG}: wrote {out} ({size / 1024:.0f} KiB, {sum(counts.values())} messages, "
          f"{t_all[-1] - t_all[0]:.3f} s, {sampling['mode']} sampling, noise "
          f"{np.asarray(args.noise).tolist()}, "
          f"uncertainty {'on' if args.uncertainty else 'off'}, seed {args.seed}) in "
          f"{total:.2f} s (simulation {sim_time:.2f} s); topics: {listing}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
