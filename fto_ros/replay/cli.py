"""``fto-replay BAG --params FILE --out OUT``: replay a bag offline, write outputs and metrics.

Exit codes (the same contract as every fto_ros command): 0 done; 2 bad parameters
or arguments (a params file or a value the schema refuses, a usage error, an ``--out``
that is empty, is the input, is inside it or holds it, or that ``--overwrite`` may not
replace because fto_ros did not write it); 1 a bad bag or a runtime failure (missing,
corrupt or undecodable bag, a topic missing, an existing output without
``--overwrite``, a replay that accepted no sample or fewer than ``--min-accepted`` of
them); 130 interrupted.  Always one ``fto-replay: error:
...`` line on stderr, never a traceback; ``FTO_DEBUG=1`` shows the traceback of
an unexpected error.
"""
from __future__ import annotations

import argparse
import os
import sys

from ..core.command_line import fraction, non_negative_float, one_line, positive_float

PROG = "fto-replay"


def build_parser() -> argparse.ArgumentParser:
    from .replay import DEFAULT_MIN_ACCEPTED, DEFAULT_NODE_NAME, DEFAULT_TOLERANCE
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Replay a rosbag2 bag through an fto_ros observer offline (no DDS), exactly "
                    "as the live node would run it. Writes OUT as a rosbag2 MCAP bag (estimates, "
                    "convergence, diagnostics, the bag's ground truth) plus OUT/metrics.json and "
                    "OUT/replay.png.")
    p.add_argument("bag", metavar="BAG", help="input bag (rosbag2 directory or .mcap file)")
    p.add_argument("--params", required=True, metavar="FILE", action="append",
                   help="ROS 2 params file of the observer node (e.g. config/dc_motor_luenberger.yaml); "
                        "give it several times to merge files in order, later ones overriding "
                        "earlier ones (a plant file, then a tuning file), as ROS 2 merges "
                        "several --params-file")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override one parameter after the files (the value is read as ROS reads "
                        "-p NAME:=VALUE), e.g. --set single_delay.tau=0.05")
    p.add_argument("--out", required=True, metavar="OUT", help="output bag directory")
    p.add_argument("--node-name", default=None, metavar="N",
                   help=f"node name: selects the params block and the output namespace "
                        f"(default {DEFAULT_NODE_NAME})")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing OUT, only if it is an empty folder or an output "
                        "fto_ros wrote (never a file, a symlink, a device or another folder)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--after", type=non_negative_float, default=None, metavar="T",
                   help="settle time (s after the observer starts) for the 'after settling' "
                        "errors (default: metrics.settle_time of the params file, else the "
                        "guaranteed time + 0.01 s, or 0.11 s without one)")
    p.add_argument("--min-accepted", type=fraction, default=DEFAULT_MIN_ACCEPTED, metavar="F",
                   help=f"fail (exit 1) when fewer than this fraction of the measurement samples "
                        f"is accepted (default {DEFAULT_MIN_ACCEPTED:g}; a replay that accepts "
                        f"none always fails)")
    p.add_argument("--tolerance", type=positive_float, default=DEFAULT_TOLERANCE, metavar="TOL",
                   help=f"error bound (state units) defining the measured convergence time "
                        f"(default {DEFAULT_TOLERANCE:g})")
    return p


def _fmt(v, spec=".3g") -> str:
    return "n/a" if v is None else format(v, spec)


def joint_lines(je: dict, settle: float) -> list[str]:
    """The per-joint errors, each field in its own unit: RMS (max) after the settle time."""
    fields, units = je["fields"], je.get("units") or {}
    head = ", ".join(f"{f}" + (f" [{units[f]}]" if units.get(f) else "") for f in fields)
    lines = [f"  after {settle:g} s, RMS (max) |error| per joint: {head}"]
    rows = list(je["per_joint"].items()) + [("all joints", je["all_joints"])]
    width = max(len(name) for name, _ in rows)
    for name, st in rows:
        per = st["per_state"]
        lines.append(f"    {name:<{width}}  " + "  ".join(
            f"{f} {_fmt(per[f]['rms_after_settle'])} ({_fmt(per[f]['max_abs_after_settle'])})"
            for f in fields))
    return lines


def summary(m: dict) -> str:
    """A few human-readable lines about a replay's metrics."""
    lines = [f"{m['observer_type']} on {m['bag']}: {m['samples_accepted']} samples accepted, "
             f"{m['samples_rejected']} rejected"
             + (f" ({', '.join(f'{k}: {v}' for k, v in m['rejected_by_reason'].items())})"
                if m["rejected_by_reason"] else "")
             + (f", {m['restarts']} restart(s)" if m["restarts"] else "")]
    gt = m["guaranteed_time_s"]
    lines.append(f"  guaranteed time: {'none' if gt is None else f'{gt:g} s'}; measured "
                 f"convergence time (tol {m['tolerance']:g}): "
                 f"{_fmt(m['convergence_time_s'], '.4g')}"
                 + ("" if m["convergence_time_s"] is None else " s"))
    if m.get("joint_errors"):
        lines += joint_lines(m["joint_errors"], m["settle_time_s"])
    elif m["errors"]:
        per = m["errors"]["per_state"]
        lines.append(f"  after {m['settle_time_s']:g} s: max |error| "
                     + ", ".join(f"{k} {_fmt(v['max_abs_after_settle'])}" for k, v in per.items())
                     + "; RMS " + ", ".join(f"{k} {_fmt(v['rms_after_settle'])}"
                                            for k, v in per.items()))
    else:
        lines.append(f"  {m['errors_note'] or 'no error metrics (no ground truth)'}")
    if m.get("unknown_input_errors"):
        per = m["unknown_input_errors"]["per_state"]
        lines.append(f"  unknown input after {m['settle_time_s']:g} s: max |error| "
                     + ", ".join(f"{k} {_fmt(v['max_abs_after_settle'])}" for k, v in per.items())
                     + "; RMS " + ", ".join(f"{k} {_fmt(v['rms_after_settle'])}"
                                            for k, v in per.items()))
    elif m.get("unknown_input_errors_note"):
        lines.append(f"  {m['unknown_input_errors_note']}")
    u = m["update_time_us"]
    lines.append(f"  update p50/p99: {_fmt(u['p50'], '.1f')} / {_fmt(u['p99'], '.1f')} us; "
                 f"replay {_fmt(m['replay_speed_x_realtime'], '.1f')}x real time "
                 f"({m['bag_duration_s']:.3g} s of bag in {m['timing_s']['replay_total']:.3g} s)")
    lines.append(f"  wrote {m['output_bag']} (+ metrics.json"
                 + (", replay.png)" if m.get("plot") else ")"))
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)  # usage errors: exit 2 with argparse's message
    try:
        from ..bag import BagError
        from ..core.errors import ConfigError
        from ..core.output_dir import OutputError
        from .replay import ReplayError, replay
        from ..runner.params_file import parse_override
        overrides = dict(parse_override(text) for text in args.set)
        metrics = replay(args.bag, args.params, args.out, node_name=args.node_name,
                         overwrite=args.overwrite, progress=not args.no_progress,
                         after=args.after, tolerance=args.tolerance, overrides=overrides,
                         min_accepted=args.min_accepted)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except (ConfigError, OutputError) as err:
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 2
    except (BagError, ReplayError, OSError) as err:
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 1
    except Exception as err:  # never a traceback for the user; FTO_DEBUG=1 shows it
        if os.environ.get("FTO_DEBUG"):
            raise
        print(f"{PROG}: error: unexpected {type(err).__name__}: {one_line(err)} "
              f"(FTO_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
    print(summary(metrics))
    return 0


if __name__ == "__main__":
    sys.exit(main())
