"""``fto-tune BAG --params FILE... --out TUNED.yaml``: each joint's bandwidth (or gain scale)
from a contact-free bag, by a residual the data can check, never against a truth.

Usage::

    fto-tune BAG --params config/arm7_plant.yaml --params config/arm7_joint_kalman.yaml
             --out tuned.yaml [--score prediction|heldout] [--after S] [--points N]
             [--set NAME=VALUE] [--node-name N] [--overwrite]

The bag is read once and replayed through the runner (the node's code path) for every
candidate: a coarse geometric grid of ``--points`` values over the knob's range (the same
value for every joint in one run: the joints' observers are independent), then, per joint,
a finer grid of 9 values between the coarse neighbours of its minimum (one run each,
every joint at its own value through ``joint_overrides``).  What is tuned and the scores:
cli/tuning.py.  It prints each joint's value with the minimum of its residual curve (and
the curve's value at the coarse neighbours, to show how flat it is), then writes TUNED.yaml:
a params file to merge after the others (``--params TUNED.yaml`` for fto-replay,
``--params-file`` for the node) that sets the per-joint values as ``joint_overrides``
entries (other joints' overrides of the input files kept), or the parameters themselves
with one observer.

Writes only its ``--out`` file: never an input (the bag, a params file), and an existing
file only with ``--overwrite`` and only when fto-tune wrote it (its first line).  Exit
codes: 0 done; 2 bad parameters or arguments (a params file the schema refuses, an
observer fto-tune has no knob for, a refused --out); 1 a bad bag or a runtime failure
(unreadable bag, no usable sample, an existing output without --overwrite).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from ..core.command_line import guarded, non_negative_float, one_line, positive_int

PROG = "fto-tune"
#: the first line of every file fto-tune writes: what --overwrite may replace
MARKER = "# written by fto-tune (fto_ros); --overwrite may replace this file"
#: finer values per joint between the coarse neighbours of its minimum
REFINE = 9


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Tune each joint's bandwidth or gain "
                                "scale on a contact-free bag by the one-step-ahead position "
                                "prediction error (or a held-out encoder subsample); write a "
                                "params file the node and fto-replay read.")
    p.add_argument("bag", metavar="BAG", help="a contact-free bag (rosbag2 directory)")
    p.add_argument("--params", required=True, action="append", metavar="FILE",
                   help="params files, merged in order (as fto-replay)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override one parameter after the files")
    p.add_argument("--out", required=True, metavar="TUNED.yaml", help="the params file to write")
    p.add_argument("--score", choices=("prediction", "heldout"), default="prediction",
                   help="prediction: the one-step-ahead position prediction error (default); "
                        "heldout: run on the even samples, score the odd ones")
    p.add_argument("--after", type=non_negative_float, default=None, metavar="S",
                   help="score from this long after the first sample (default: "
                        "metrics.settle_time of the params, else 0.5 s)")
    p.add_argument("--points", type=positive_int, default=25, metavar="N",
                   help="coarse grid points over the knob's range (default 25)")
    p.add_argument("--node-name", default=None, metavar="N")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out, only a file fto-tune wrote")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    return guarded(PROG, _main, build_parser().parse_args(argv))


def _fail(message: Any, code: int) -> int:
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return code


def _main(args: argparse.Namespace) -> int:
    from ..bag import BagError
    from ..core.errors import ConfigError
    from ..core.output_dir import OutputError, OutputExists, check_output_file
    from ..replay.topics import ReplayError
    try:
        out = check_output_file(args.out, MARKER, overwrite=args.overwrite,
                                inputs=[args.bag, *args.params])
        result = tune(args)
        write_tuned(out, result)
    except (ConfigError, OutputError) as err:
        return _fail(err, 2)
    except (BagError, ReplayError, OutputExists, OSError) as err:
        return _fail(err, 1)
    print(result["table"])
    print(f"{PROG}: wrote {out}")
    return 0


def _plain(v: Any) -> Any:
    """Python floats (lists of them) for the YAML writer."""
    return [_plain(x) for x in v] if isinstance(v, (list, tuple, np.ndarray)) else float(v)


def _nested(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in flat.items():
        node = out
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def write_tuned(path: Path, result: dict[str, Any]) -> None:
    """The params file: fto-tune's first line, what was done as comments, the values."""
    body = yaml.safe_dump({"/**": {"ros__parameters": _nested(result["params"])}},
                          sort_keys=False, default_flow_style=None, width=100)
    text = "\n".join([MARKER] + ["# " + line for line in result["comment"]]) + "\n" + body
    fd, tmp = tempfile.mkstemp(prefix=".fto-tune-", dir=os.path.dirname(os.path.abspath(path)))
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# -- the search ---------------------------------------------------------------------------------
def _runner(flat, knob_, values, joints):
    from ..core.errors import ConfigError
    from ..runner.runner import Runner
    from .tuning import with_values
    try:
        return Runner(with_values(flat, joints, knob_.apply(values)))
    except ConfigError:
        return None                      # a candidate the observer refuses (e.g. hosm's M bound)


def tune(args: argparse.Namespace) -> dict[str, Any]:
    """Search each joint's value; the table to print, the params and the file's comment."""
    from ..replay.run import bag_rows
    from ..replay.topics import ReplayError, node_fqn
    from ..runner import joints as JX
    from ..runner.params_file import load_params_files, parse_override
    from ..runner.runner import Runner
    from . import tuning as T
    overrides = dict(parse_override(text) for text in args.set)
    flat = load_params_files([Path(p) for p in args.params], args.node_name, overrides)
    base = Runner(flat)
    joints = list(base.joints)
    flats = JX.per_joint(flat, joints) if joints else [flat]
    kn = T.knob(base, flats)
    _, _, rows = bag_rows(base, Path(args.bag), node_fqn(args.node_name))
    keep = T.heldout_mask(rows) if args.score == "heldout" else None
    after = args.after if args.after is not None else \
        (base.settings["metrics.settle_time"] or 0.5)
    J = base.n_joints

    def run(values: np.ndarray) -> np.ndarray:
        r = _runner(flat, kn, values, joints)
        return np.full(J, np.inf) if r is None else T.score(r, rows, keep, after)

    coarse = np.geomspace(kn.lo, kn.hi, max(args.points, 3))
    curve = np.array([run(np.full(J, v)) for v in coarse])          # (points, J)
    curve = np.where(np.isnan(curve), np.inf, curve)
    if not np.isfinite(curve).any():
        raise ReplayError(f"no usable samples to score in {args.bag} (every candidate "
                          "rejected, or no accepted measurement pairs after --after)")
    best_i = np.argmin(curve, axis=0)
    lo = coarse[np.maximum(best_i - 1, 0)]
    hi = coarse[np.minimum(best_i + 1, coarse.size - 1)]
    fine = np.exp(np.linspace(np.log(lo), np.log(hi), REFINE))          # (REFINE, J)
    fine_scores = np.array([run(fine[k]) for k in range(REFINE)])
    fine_scores = np.where(np.isnan(fine_scores), np.inf, fine_scores)
    k = np.argmin(fine_scores, axis=0)
    cols = np.arange(J)
    chosen = fine[k, cols]
    best = fine_scores[k, cols]
    worse = best > curve[best_i, cols]                    # keep the coarse point if better
    chosen = np.where(worse, coarse[best_i], chosen)
    best = np.where(worse, curve[best_i, cols], best)
    final = _runner(flat, kn, chosen, joints)
    if final is None:
        raise ReplayError("the tuned values are refused by the observer (see fto-replay with "
                          "the written file)")
    names = joints or ["(observer)"]
    edge = (best_i == 0) | (best_i == coarse.size - 1)
    head = (f"{'joint':<14} {kn.parameter + (' (' + kn.unit + ')' if kn.unit else ''):<40} "
            f"{'residual min (rad)':>18} {'at coarse -1 / +1':>22}")
    lines = [head]
    for j, name in enumerate(names):
        nb = [curve[max(best_i[j] - 1, 0), j], curve[min(best_i[j] + 1, coarse.size - 1), j]]
        note = "  (at the edge of the range)" if edge[j] else \
            "  (a neighbour refused by the observer)" if not np.all(np.isfinite(nb)) else ""
        lines.append((f"{name:<14} {kn.shown(float(chosen[j]), j):<40} {best[j]:>18.4g} "
                      f"{nb[0]:>10.4g} / {nb[1]:<10.4g}" + note).rstrip())
    table = "\n".join([f"{PROG}: {base.observer_type} on {args.bag}, score {args.score} "
                       f"(RMS, from {after:g} s), {coarse.size} + {REFINE} runs"] + lines)
    if joints:        # every override of the inputs kept, the tuned ones replaced
        params = {JX.OVERRIDES: T.with_values(flat, joints, kn.apply(chosen))[JX.OVERRIDES]}
    else:
        params = {name: _plain(v[0]) for name, v in kn.apply(chosen).items()}
    comment = [f"bag: {args.bag}", "params: " + ", ".join(args.params),
               f"score: {args.score} (RMS from {after:g} s); merge this file after them"] + lines
    return {"table": table, "params": params, "comment": comment, "chosen": chosen,
            "residual": best, "curve": curve, "grid": coarse, "joints": names}
