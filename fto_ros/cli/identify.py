"""``fto-identify BAG --params FILE... --out PARAMS.yaml``: an arm's friction and inertial
corrections identified from a contact-free stretch of a bag (docs/identify.md).

Usage::

    fto-identify BAG --params PLANT.yaml [MORE.yaml ...] --out IDENTIFIED.yaml
                 [--topic NAME] [--start S] [--end S] [--segment A:B ...]
                 [--inertia base|scale|none] [--links L1,L2,...] [--frame FRAME]
                 [--payload-only] [--no-friction]
                 [--window S] [--stride N] [--max-gap S] [--ratio R] [--outlier Z]
                 [--encoder-noise RAD] [--node-name NAME] [--overwrite]

Reads the JointState stream (positions, efforts, header stamps) of the params' joints,
the URDF and the effort's meaning from the params files (merged in order, as the node
merges them), fits the momentum identity's window form on the stretch chosen
(:mod:`fto_ros.arm.identify`), prints the fit (each unknown's prior, value and standard
error, the residual per joint against the encoder noise, the condition number, what was
refused) and writes ``--out``: a ROS 2 params file with the values fitted, which the node
and the replay merge after the plant file. Times (``--start``, ``--end``, ``--segment``)
are seconds from the stream's first message.

Writes only ``--out`` (never an input; an existing file only with ``--overwrite`` and only
one fto-identify wrote). Exit codes: 0 done; 2 bad arguments or parameters; 1 a bad bag or
a fit the data cannot support.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from ..arm.identify import INERTIA_FORMS, Identified, Spec, identify
from ..arm.identify_fit import FitRefused
from ..arm.identify_params import MARKER, params_text, prior_model, read
from ..arm.identify_windows import WindowError
from ..bag import BagError
from ..core.command_line import guarded, non_negative_float, one_line, positive_float, \
    positive_int
from ..core.errors import ConfigError
from ..core.output_dir import OutputError, OutputExists, check_output_file
from ..runner.params_file import DEFAULT_NODE_NAME, load_params_files
from .identify_stream import StreamError, read_stream, stretch_mask

PROG = "fto-identify"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        self.exit(2, f"{PROG}: error: {' '.join(message.split())}\n")


def _segment(text: str) -> tuple[float, float]:
    a, sep, b = text.partition(":")
    try:
        lo, hi = float(a), float(b)
    except ValueError:
        lo = hi = float("nan")
    if not sep or not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise argparse.ArgumentTypeError(f"expected A:B with A < B (seconds), got {text!r}")
    return lo, hi


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Identify an arm's friction and inertial corrections "
                "from a contact-free stretch of a bag (docs/identify.md).")
    a = p.add_argument
    a("bag", help="the rosbag2 bag with the arm's JointState stream")
    a("--params", nargs="+", required=True, metavar="FILE",
      help="params files (the plant file first; merged in order)")
    a("--out", required=True, metavar="PARAMS.yaml", help="the params file to write")
    a("--topic", help="the JointState stream (default: topics.joint_states)")
    a("--start", type=non_negative_float, metavar="S", help="first second of the stretch")
    a("--end", type=positive_float, metavar="S", help="last second of the stretch")
    a("--segment", type=_segment, action="append", default=[], metavar="A:B",
      help="a contact-free stretch [A, B] s (repeatable; the fit uses them together)")
    a("--inertia", choices=INERTIA_FORMS, default="base",
      help="inertial unknowns: base (the base parameters of the bodies), scale (a factor per "
           "link), none (friction only); default base")
    a("--links", help="--inertia scale: the links scaled (default: every link that moves)")
    a("--frame", help="a payload at this frame (default: payload.frame of the params)")
    a("--payload-only", action="store_true",
      help="fit only the payload at --frame (a short stretch after a grasp; friction and "
           "inertias fixed)")
    a("--no-friction", action="store_true", help="keep the params' friction")
    a("--window", type=positive_float, default=0.1, metavar="S",
      help="the kernel's length T (default 0.1 s)")
    a("--stride", type=positive_int, default=10, metavar="N",
      help="one window every N samples (default 10)")
    a("--max-gap", type=positive_float, default=0.01, metavar="S",
      help="no window over a step longer than this (default 0.01 s)")
    a("--ratio", type=positive_float, default=0.5, metavar="R",
      help="refuse an unknown whose standard error exceeds R times its value (default 0.5)")
    a("--outlier", type=non_negative_float, default=30.0, metavar="Z",
      help="windows whose residual exceeds Z robust standard deviations are contacts, left "
           "out (default 30; 0: keep all)")
    a("--encoder-noise", type=positive_float, metavar="RAD",
      help="the encoder's noise (default: estimated from the positions)")
    a("--node-name", default=DEFAULT_NODE_NAME, help="whose block of the params files to read")
    a("--overwrite", action="store_true", help="replace --out (only a file fto-identify wrote)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run fto-identify; returns the exit code."""
    return guarded(PROG, _run, build_parser().parse_args(argv))


def _fail(message, code: int) -> int:
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return code


def _run(args) -> int:
    started = time.perf_counter()
    try:
        out = check_output_file(args.out, MARKER, overwrite=args.overwrite,
                                inputs=[args.bag, *args.params])
        settings = read(load_params_files(args.params, args.node_name))
        model = prior_model(settings)
        spec = _spec(args, settings)
    except (ConfigError, OutputError) as err:
        return _fail(err, 2)
    except OutputExists as err:
        return _fail(err, 1)
    try:
        stream = read_stream(args.bag, args.topic, settings["topics.joint_states"],
                             model.joints, model.passive_joints, model.passive_default)
        mask = stretch_mask(stream.t, args.start, args.end, args.segment)
        if not mask.any():
            raise StreamError(f"no sample in the stretch chosen (the stream lasts "
                              f"{stream.t[-1]:.3f} s)")
        keep = np.flatnonzero(mask)
        lo, hi = keep[0], keep[-1] + 1                   # the stretch's span, gaps masked
        result = identify(model, stream.t[lo:hi], stream.q[lo:hi], stream.effort[lo:hi],
                          stream.passive[lo:hi], spec, mask=mask[lo:hi])
    except ConfigError as err:
        return _fail(err, 2)
    except (BagError, StreamError, WindowError, FitRefused) as err:
        return _fail(err, 1)
    report = summary(result, stream, stream.t[lo:hi])
    print("\n".join(report))
    try:
        Path(out).write_text(params_text(result.parameters(), comments(result, args, stream)))
    except OSError as err:
        return _fail(f"cannot write {out}: {err.strerror}", 1)
    print(f"{PROG}: wrote {out} ({time.perf_counter() - started:.1f} s)")
    return 0


def _spec(args, s) -> Spec:
    frame = args.frame if args.frame is not None else s["payload.frame"]
    if args.payload_only and not frame:
        raise ConfigError("--frame", "--payload-only needs the payload's frame (--frame or "
                                     "payload.frame)")
    if args.frame and args.inertia == "base" and not args.payload_only:
        raise ConfigError("--frame", "with --inertia base a payload is part of its body's base "
                                     "parameters: use --inertia scale, or --payload-only")
    if args.links and args.inertia != "scale":
        raise ConfigError("--links", "only with --inertia scale")
    links = tuple(x.strip() for x in args.links.split(",") if x.strip()) if args.links else ()
    return Spec(window=args.window, stride=args.stride, max_gap=args.max_gap,
                friction=not args.no_friction, inertia=args.inertia, links=links,
                payload=frame if (args.payload_only or args.frame is not None or
                                  args.inertia == "scale") else "",
                payload_only=args.payload_only, ratio=args.ratio, outlier=args.outlier,
                encoder_noise=args.encoder_noise, effort=s["effort.meaning"],
                torque_constant=s["effort.torque_constant"] or None,
                gear_ratio=s["effort.gear_ratio"] or None)


def _g(x: float) -> str:
    return f"{x:.4g}" if np.isfinite(x) else "-"


def summary(r: Identified, stream, t) -> list[str]:
    """What fto-identify prints: the fit's figures, one unknown a line."""
    fit = r.fit
    used = fit.used
    lines = [f"{PROG}: {stream.topic}: {t.size} samples over {t[-1] - t[0]:.2f} s; "
             f"{r.windows} windows of {r.spec.window:g} s used "
             f"({fit.effective_windows:.0f} effective, inflation {fit.inflation:.2f}); "
             f"condition number {fit.cond:.3g}; effort {r.spec.effort}"]
    if stream.skipped:
        lines.append("messages skipped: " + ", ".join(f"{k} {v}" for k, v in
                                                      stream.skipped.items()))
    if not used.all():
        lines.append(f"windows left out as contacts: {int((~used).sum())} "
                     f"({_spans(r)})")
    lines.append("joint: residual RMS before -> after (Nm), encoder noise's share (Nm), ratio")
    for j, a, b, c in zip(r.model.joints, r.prior_rms, r.residual_rms, r.noise_rms):
        lines.append(f"  {j}: {_g(a)} -> {_g(b)}, {_g(c)}, {_g(b / c) if c > 0 else '-'}x")
    lines.append(f"encoder noise (rad): {', '.join(_g(x) for x in np.atleast_1d(r.encoder_noise))}")
    lines.append("unknown: prior -> fitted +- standard error")
    refused = {u.name for u, _, _ in r.refused}
    for u, v, se in zip(r.unknowns, r.value, r.se):
        tag = "  REFUSED (left at the prior)" if u.name in refused else ""
        lines.append(f"  {u.name}: {_g(u.prior)} -> {_g(v)} +- {_g(se)}{tag}")
    if refused:
        lines.append(f"refused, standard error above {r.spec.ratio:g} of the value: " +
                     ", ".join(f"{u.name} ({_g(se)} vs {_g(size)})" for u, se, size in r.refused))
    lines += [f"note: {n}" for n in r.notes]
    return lines


def _spans(r: Identified) -> str:
    """The windows left out as [first end, last end] s, one run of them each."""
    out = (~r.fit.used).astype(int)
    edges = np.diff(np.concatenate([[0], out, [0]]))
    runs = zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1)
    spans = [f"{r.window_times[a]:.2f}-{r.window_times[b]:.2f} s" for a, b in runs]
    return ", ".join(spans[:10]) + (f" and {len(spans) - 10} more" if len(spans) > 10 else "")


def comments(r: Identified, args, stream) -> list[str]:
    """The comment block of the params file: how it was made, the residual, each standard
    error, what was refused."""
    fit = r.fit
    out = [f"fto-identify {Path(args.bag).name} (topic {stream.topic}); inertia "
           f"{'payload only' if r.spec.payload_only else r.spec.inertia}; window "
           f"{r.spec.window:g} s; {r.windows} windows ({fit.effective_windows:.0f} effective); "
           f"condition number {fit.cond:.3g}",
           "residual RMS per joint (Nm) before -> after [encoder noise's share]: " +
           "; ".join(f"{j} {_g(a)} -> {_g(b)} [{_g(c)}]" for j, a, b, c in
                     zip(r.model.joints, r.prior_rms, r.residual_rms, r.noise_rms))]
    refused = {u.name for u, _, _ in r.refused}
    for u, v, se in zip(r.unknowns, r.value, r.se):
        out.append(f"{u.name}: {_g(v)} +- {_g(se)}" +
                   (" refused (left at the prior)" if u.name in refused else ""))
    out += [f"note: {n}" for n in r.notes]
    return out
