"""``fto-sweep``: replay a parameter grid over many bags, in parallel; tabulate, plot, rank.

    fto-sweep --params FILE [--params FILE ...] --bag BAG [--bag BAG ...]
              --set NAME=V1,V2,... [--set ...] --out DIR
              [--baseline FILE[,FILE...] ...] [--workers N | --scheduler ADDRESS]
              [--connect-timeout S]
              [--data shared|send] [--keep-runs] [--no-plots] [--overwrite]

Every combination of the ``--set`` values (the params files merged in order, then the
combination's overrides) is replayed on every bag through :func:`fto_ros.replay.replay`;
each ``--baseline`` (params files merged in order, without the overrides) is replayed on
the same bags.  Writes ``DIR/results.csv`` (one row per run), ``DIR/summary.txt`` (also
printed: the best setting per bag and over all bags) and the figures
(``DIR/error_vs_<NAME>.png``, ``DIR/pareto.png``).  A run that fails is a row with its
error.  See docs/sweep.md.

Exit codes: 0 done (some runs may have been refused for their parameters), 2 bad arguments
or parameters (usage, a params file, a ``--set`` name or value, an ``--out`` that exists
without ``--overwrite``, is or holds an input, or is not an earlier sweep's output, every
run refused), 1 a bad bag or a run-time failure (a missing bag, a run that failed for its
bag, an unreachable cluster within ``--connect-timeout``, a scheduler lost during the sweep:
the rows of the runs it did not finish say so, and the line follows the table), 130
interrupted.  One ``fto-sweep: error: ...`` line, never a traceback (``FTO_DEBUG=1`` shows
the traceback of an unexpected error, and distributed's own log lines).
"""
from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path


PROG = "fto-sweep"


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line usage error (exit 2)."""

    def error(self, message):
        self.exit(2, f"{PROG}: error: {' '.join(message.split())} (see {PROG} --help)\n")


def _scheduler(text: str) -> str:
    from ..core.errors import CommandLineError
    from .cluster import SCHEMES, EngineError, split_address
    if not re.fullmatch(r"[a-z][a-z0-9+.-]*://\S+", text):
        raise CommandLineError(f"expected a Dask scheduler address such as "
                                         f"tcp://HOST:8786, got {text!r}")
    try:
        split_address(text)
    except EngineError as err:
        raise CommandLineError(f"{err} ({'/'.join(SCHEMES)}://HOST:PORT)") from None
    return text


def build_parser() -> argparse.ArgumentParser:
    from ..core.command_line import non_negative_float, positive_float, positive_int
    p = _Parser(
        prog=PROG,
        description="Replay every combination of the --set values on every bag (the replay "
                    "harness's code path), in local worker processes or on a Dask cluster; "
                    "write DIR/results.csv, DIR/summary.txt and plots of error against each "
                    "swept parameter and of convergence time against error (Pareto front).")
    p.add_argument("--params", required=True, action="append", metavar="FILE",
                   help="ROS 2 params file of the observer; several are merged in order, later "
                        "ones overriding earlier ones (a plant file, then a tuning file)")
    p.add_argument("--bag", required=True, action="append", metavar="BAG",
                   help="rosbag2 bag (directory or .mcap file) with ground truth; repeat for "
                        "more bags")
    p.add_argument("--set", action="append", default=[], metavar="NAME=V1,V2,...",
                   help="swept parameter: full name (e.g. single_delay.tau) and its values, "
                        "each read as ROS reads it, like fto-replay --set; commas inside brackets or "
                        "quotes do not split, so list values work: "
                        "luenberger.process_noise=[1e-6, 0.25, 0.04],[1e-6, 1.0, 0.04]")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--baseline", action="append", default=[], metavar="FILE[,FILE...]",
                   help="a params file (or comma-separated files merged in order) replayed on "
                        "the same bags without the --set values, for comparison; repeatable "
                        "(default: none)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive_int, default=None, metavar="N",
                       help="local worker processes (default: one per core; 1 runs everything "
                            "in this process)")
    where.add_argument("--scheduler", type=_scheduler, default=None, metavar="ADDRESS",
                       help="run on the existing Dask cluster of this scheduler "
                            "(tcp://HOST:PORT, or tls://, ws://, wss://); every worker needs "
                            "fto_ros installed")
    p.add_argument("--connect-timeout", type=positive_float, default=None, metavar="S",
                   help="seconds to wait for the scheduler to answer and for its cluster to "
                        "have a worker (default 10)")
    p.add_argument("--data", choices=("shared", "send"), default="shared",
                   help="shared (default): workers open the bags and params files at their "
                        "absolute paths (this machine, or storage every worker mounts at the same "
                        "path); send: this process reads them and sends them to the workers")
    p.add_argument("--keep-runs", action="store_true",
                   help="keep each run's output bag and metrics.json in DIR/runs/ (on a cluster, "
                        "DIR must be on storage the workers share)")
    p.add_argument("--no-plots", action="store_true", help="write no figures")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR if it is an earlier sweep's output (or empty); never "
                        "anything fto-sweep did not write")
    # the defaults are fto-replay's, said in words: importing them would import the whole
    # replay before the progress bar can show (test_sweep.py checks that they agree)
    p.add_argument("--tolerance", type=positive_float, default=None, metavar="TOL",
                   help="error bound (state units) for the measured convergence time "
                        "(default 0.01, as fto-replay)")
    p.add_argument("--after", type=non_negative_float, default=None, metavar="T",
                   help="settle time (s after the observer starts) for the errors (default: the "
                        "params' metrics.settle_time, else the guaranteed time + 0.01 s, or 0.11 s)")
    p.add_argument("--node-name", default=None, metavar="N",
                   help="node name selecting the params block (default observer_node)")
    p.add_argument("--quiet", action="store_true", help="no line per finished run on stderr")
    return p


def _fail(code: int, message: str) -> int:
    from ..core.command_line import one_line
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return code


def main(argv=None) -> int:
    from ..core.command_line import guarded
    return guarded(PROG, _main, build_parser().parse_args(argv))


def _main(args) -> int:
    from ..core.progress import bar
    from .engine import prestart
    prestart(args.workers, args.scheduler)        # the workers' imports start now, beside ours
    progress = bar(0, "runs", enabled=not args.quiet)
    progress.set_postfix_str("loading")
    try:
        return _sweep(args, progress)
    finally:
        progress.close()


def _sweep(args, progress) -> int:
    from ..core.progress import say
    from ..core.errors import ConfigError
    from ..core.output_dir import OutputError, OutputExists, check_output, create_output
    from ..runner.params_file import load_params_files
    from . import grid, plots, results
    from .engine import CONNECT_TIMEOUT_S, Engine, EngineError, Lost
    from .tasks import RUNTIME, Outcome, Run, bag_size, execute, read_files
    from ..replay import DEFAULT_TOLERANCE
    if args.tolerance is None:
        args.tolerance = DEFAULT_TOLERANCE

    # ---- everything that can be refused before a single run (exit 2, then 1)
    baselines = [tuple(f.strip() for f in b.split(",") if f.strip()) for b in args.baseline]
    try:
        axes = grid.parse_axes(args.set)
        flat = load_params_files(args.params, args.node_name)
        grid.check_axes(axes, flat)
        for files in baselines:
            load_params_files(files, args.node_name)
    except ConfigError as err:
        return _fail(2, str(err))
    inputs = [*args.bag, *args.params, *(f for files in baselines for f in files)]
    try:
        out = check_output(args.out, "sweep", overwrite=args.overwrite, inputs=inputs)
    except (OutputError, OutputExists) as err:
        return _fail(2, str(err))
    for bag in args.bag:
        if not Path(bag).exists():
            return _fail(1, f"bag {bag} does not exist")

    # ---- the runs: the grid on every bag, then the baselines on every bag
    settings = grid.expand(axes)
    plan = [(bag, tuple(args.params), s) for bag in args.bag for s in settings]
    plan += [(bag, files, None) for bag in args.bag for files in baselines]
    runs = [Run(i, bag, params, bag_path=str(Path(bag).resolve()),
                params_paths=tuple(str(Path(f).resolve()) for f in params),
                overrides={} if setting is None else dict(setting.overrides),
                out=str(out.resolve() / "runs" / f"{i:04d}_{Path(bag).name}")
                if args.keep_runs else None,
                node_name=args.node_name, tolerance=args.tolerance, after=args.after, brief=True)
            for i, (bag, params, setting) in enumerate(plan)]
    costs = {bag: bag_size(bag) for bag in args.bag}

    done = [0]

    progress.total = len(runs)
    progress.set_postfix_str("starting the workers")

    def on_done(i, outcome) -> None:
        done[0] += 1
        progress.set_postfix_str("")
        progress.update(1)
        if args.quiet:
            return
        run, setting = runs[i], plan[i][2]
        what = f"baseline {','.join(run.params)}" if setting is None else setting.label()
        state = getattr(outcome, "error", None) or getattr(outcome, "message", None)
        say(progress, f"{PROG}: [{done[0]}/{len(runs)}] {run.bag}, {what}: "
            + (f"FAILED: {state}" if state else "ok"))

    t0 = time.perf_counter()
    try:
        with Engine(workers=args.workers, scheduler=args.scheduler,
                    connect_timeout=args.connect_timeout or CONNECT_TIMEOUT_S) as engine:
            files = sorted({r.bag_path for r in runs} | {p for r in runs for p in r.params_paths})
            if args.data == "shared":
                for worker, missing in engine.missing_paths(files).items():
                    more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
                    return _fail(1, f"worker {worker} cannot see {missing[0]}{more}: put the bags "
                                    "and params files on storage every worker mounts at the same "
                                    "path, or pass --data send")
                arglists = [(r,) for r in runs]
            else:
                sent = {f: engine.share(read_files(f)) for f in files}
                arglists = [(r, sent[r.bag_path], tuple(sent[p] for p in r.params_paths))
                            for r in runs]
            try:
                create_output(out, "sweep", overwrite=args.overwrite, inputs=inputs)
            except (OutputError, OutputExists) as err:
                return _fail(2, str(err))
            if not args.quiet:
                say(progress, f"{PROG}: {len(runs)} run(s) on {engine.description}")
            outcomes = engine.map(execute, arglists, costs=[costs[r.bag] for r in runs],
                                  on_done=on_done)
            description, lost = engine.description, engine.lost
    except EngineError as err:
        return _fail(1, str(err))
    wall = time.perf_counter() - t0

    # ---- results
    rows = []
    for run, (_bag, _params, setting), outcome in zip(runs, plan, outcomes):
        if isinstance(outcome, Lost):
            outcome = Outcome(run.index, error=outcome.message, kind=RUNTIME)
        rows.append(results.make_row(run, setting, outcome, axes))
    progress.close()
    text = results.summary(rows, len(settings), description, wall, args.tolerance)
    try:
        results.write_csv(out / "results.csv", rows, axes)
        (out / "summary.txt").write_text(text + "\n")
        if not args.no_plots:
            plots.write_all(out, axes, rows)
    except OSError as err:
        from ..core.output_dir import abandon
        what = abandon(out, "sweep", f"{err.strerror or err}", keep=True)
        return _fail(1, f"cannot write the results in {out}: {err.strerror or err}; {what}")
    print(text)
    print(f"wrote {out / 'results.csv'}, {out / 'summary.txt'}"
          + ("" if args.no_plots else f" and the figures in {out}"))
    if lost is not None:
        undone = sum(1 for o in outcomes if isinstance(o, Lost) and o.message.startswith("not run"))
        return _fail(1, f"{lost}: {undone} of {len(runs)} run(s) not done (their rows say so)")
    return results.exit_code(rows)


if __name__ == "__main__":
    sys.exit(main())
