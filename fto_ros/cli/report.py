"""``fto-report``: replay the DC-motor bags through every observer and compare them.

Each (bag, params file) pair is replayed with :func:`fto_ros.replay.replay`
into ``OUT/<bag>__<config>/`` (output bag, ``metrics.json``, ``replay.png``),
the pairs in parallel on fto-sweep's engine (:mod:`fto_ros.sweep.engine`: one
worker process per core by default, ``--workers 1`` one after the other in this
process); then a side-by-side markdown table is printed and written to
``OUT/report.md`` with links to the plots.

The pairs are data, not code (:func:`plan`):

- bags: ``BAGS_DIR/dc_motor_*`` (``dc_motor_nominal`` and ``dc_motor_noisy``
  are required: a missing one is a failed row; the others, e.g.
  ``dc_motor_sampled``, are used when present);
- configs: ``CONFIG_DIR/dc_motor_*.yaml`` whose ``observer.type`` is a
  registered observer (others are skipped with a note);
- a config ``X_<variant>.yaml`` (e.g. ``dc_motor_single_delay_sampled.yaml``)
  replaces ``X.yaml`` for the bag ``dc_motor_<variant>`` and is used for no
  other bag;
- ``CONFIG_DIR/<system>_plant.yaml`` is a system's plant file, not a config: it is
  merged first for every ``<system>_*.yaml`` that has no model of its own
  (:mod:`fto_ros.runner.plant_files`).

``OUT`` is replaced on every run when it holds an earlier report (or is empty or new);
anything else (a file, a symlink, a folder fto-report did not write, the bags or
configs) is refused.

Exit code 0 when every replay succeeded, 1 otherwise (the table is printed
either way, failed rows included), 2 for usage errors and a refused ``OUT``.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.output_dir import REPORT_TITLE, OutputError, abandon, check_output, create_output


PROG = "fto-report"
SYSTEM = "dc_motor"
#: bags that must be there; every other BAGS_DIR/dc_motor_* is used when present
REQUIRED_BAGS = ("dc_motor_nominal", "dc_motor_noisy")
#: row order: these bags and observers first (in this order), the rest alphabetically
BAG_ORDER = ("dc_motor_nominal", "dc_motor_noisy", "dc_motor_collision", "dc_motor_sampled")
CONFIG_ORDER = ("dc_motor_single_delay", "dc_motor_luenberger", "dc_motor_acquire_track")


@dataclass
class Pair:
    """One replay of the report."""

    bag: Path
    config: Path
    out: Path = field(default=Path())
    metrics: dict[str, Any] | None = None
    error: str | None = None
    #: the example system (table) this pair belongs to, when not the DC motor
    system: str | None = None
    #: the system's plant file, merged before ``config`` (None: the config is complete)
    plant: Path | None = None

    @property
    def name(self) -> str:
        return f"{self.bag.name}__{self.config.stem}"

    @property
    def params(self) -> list[Path]:
        """The params files of the replay, merged in order."""
        return [self.plant, self.config] if self.plant else [self.config]


def _configs(config_dir: Path, pattern: str) -> list[Path]:
    """The params files matching ``pattern``, plant files left out (they are no configs)."""
    from ..runner.plant_files import is_plant_file
    return [p for p in sorted(config_dir.glob(pattern)) if not is_plant_file(p)]


def _ordered(names, preferred) -> list:
    rank = {n: i for i, n in enumerate(preferred)}
    return sorted(names, key=lambda n: (rank.get(n, len(rank)), n))


def _observer_type(config: Path) -> str | None:
    """observer.type of a params file, or None if it cannot be read."""
    from ..runner.settings import load_params_file
    try:
        return load_params_file(config).get("observer.type")
    except Exception:
        return None


def plan(bags_dir: Path, config_dir: Path) -> tuple[list[Pair], list[str]]:
    """The (bag, config) pairs to replay, and notes on what was skipped and why."""
    from ..observers import REGISTRY
    notes: list[str] = []
    present = {p.name for p in bags_dir.glob(f"{SYSTEM}_*") if p.is_dir() or p.suffix == ".mcap"}
    bag_names = _ordered(present | set(REQUIRED_BAGS), BAG_ORDER)
    variants = {b[len(SYSTEM) + 1:] for b in bag_names} | {b[len(SYSTEM) + 1:] for b in BAG_ORDER}
    from ..runner.plant_files import plant_file_for
    configs = {p.stem: p for p in _configs(config_dir, f"{SYSTEM}_*.yaml")}
    if not configs:
        notes.append(f"no {SYSTEM}_*.yaml params files in {config_dir}")
    # a config 'X_<variant>' is the variant of 'X' when 'X' exists too
    base = [c for c in configs if not any(c.endswith("_" + v) and c[:-len(v) - 1] in configs
                                          for v in variants)]
    usable = []
    for stem in _ordered(base, CONFIG_ORDER):
        kind = _observer_type(configs[stem])
        if kind is not None and kind not in REGISTRY:
            notes.append(f"skipped {configs[stem]}: observer '{kind}' is not available "
                         f"(known: {', '.join(sorted(REGISTRY))})")
            continue
        usable.append(stem)  # unreadable configs stay: their replay reports the problem
    pairs = []
    for bag in bag_names:
        variant = bag[len(SYSTEM) + 1:]
        for stem in usable:
            cfg = configs.get(f"{stem}_{variant}", configs[stem])
            pairs.append(Pair(bags_dir / bag, cfg, plant=plant_file_for(cfg)))
    return pairs, notes


def example_system(bag: str, config_dir: Path) -> str | None:
    """The example system a bag belongs to: the longest ``S`` with ``bag == S`` or
    ``bag == S_<variant>`` for which ``CONFIG_DIR/S_*.yaml`` exist (None: no config)."""
    parts = bag.split("_")
    for k in range(len(parts), 0, -1):
        system = "_".join(parts[:k])
        if any(config_dir.glob(f"{system}_*.yaml")):
            return system
    return None


def plan_examples(bags_dir: Path, config_dir: Path) -> list[Pair]:
    """The other example systems: every bag ``BAGS_DIR/<system>[_<variant>]`` (not the DC
    motor's) with every ``CONFIG_DIR/<system>_*.yaml`` (e.g. the prescribed-time examples;
    ``possieri_example_sinusoid`` is a variant of ``possieri_example``)."""
    from ..runner.plant_files import plant_file_for
    pairs = []
    for bag in sorted(p for p in bags_dir.iterdir() if p.is_dir() and not p.name.startswith(SYSTEM)):
        system = example_system(bag.name, config_dir)
        if system is not None:
            pairs += [Pair(bag, cfg, system=system, plant=plant_file_for(cfg))
                      for cfg in _configs(config_dir, f"{system}_*.yaml")]
    return pairs


def system_of(pair: Pair) -> str:
    """The system a pair belongs to (one table per system)."""
    return pair.system or (SYSTEM if pair.bag.name.startswith(SYSTEM) else pair.bag.name)


def tables(pairs: list[Pair]) -> str:
    """One side-by-side table per system (their states differ)."""
    from .torque_table import is_arm
    out = []
    pairs = [p for p in pairs if not is_arm(p)]        # their own table (torque_table.py)
    for system in dict.fromkeys(system_of(p) for p in pairs):
        group = [p for p in pairs if system_of(p) == system]
        jointed = any(p.metrics and p.metrics.get("joints") for p in group)
        out += [f"**{system}**", "", (joint_table if jointed else table)(group), ""]
        composed = [p for p in group if p.metrics and p.metrics.get("composition")]
        if composed:
            out += [f"*{system}, acquire then track* (the `track` rows above)", "",
                    composition_table(composed), ""]
    return "\n".join(out).rstrip()


def composition_table(pairs: list[Pair]) -> str:
    """Acquisition time, hand-overs and re-acquisitions (with their times) of the
    compositions' replays."""
    rows = [["bag", "params", "acquisition time (s)", "hand-overs", "re-acquisitions",
             "re-acquired at (s)"], ["---"] * 6]
    for p in pairs:
        c = p.metrics["composition"]
        rows.append([p.bag.name, p.config.name, _g(c["acquisition_time_s"], 4),
                     str(c["handovers"]), str(c["reacquisitions"]),
                     ", ".join(_g(t, 4) for t in c["reacquisition_times_s"]) or "-"])
    return "\n".join("| " + " | ".join(row) + " |" for row in rows)


# ------------------------------------------------------------------------ table
def _g(v, digits: int = 3) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and not math.isfinite(v):
        return "n/a"
    if v == 0:
        return "0"
    return f"{v:.{digits}g}"


def _state_columns(pairs: list[Pair]) -> list[str]:
    """One label per state index; names that differ between observers are joined with '/'."""
    labels: list[list[str]] = []
    for p in pairs:
        if p.metrics:
            for i, name in enumerate(p.metrics["state_names"]):
                while len(labels) <= i:
                    labels.append([])
                if name not in labels[i]:
                    labels[i].append(name)
    return ["/".join(names) for names in labels]


def _unknown_input_errors(pair: Pair) -> dict:
    """Per unknown input, the error statistics of a replay (empty without truth or estimate)."""
    errs = (pair.metrics or {}).get("unknown_input_errors") or {}
    return errs.get("per_state") or {}


def table(pairs: list[Pair]) -> str:
    """The side-by-side markdown table of the replays."""
    states = _state_columns(pairs)
    unknown = list(dict.fromkeys(name for p in pairs for name in _unknown_input_errors(p)))
    head = (["bag", "observer (params)", "guaranteed time (s)", "measured convergence (s)",
             "settle (s)"]
            + [f"max abs err {s}" for s in states] + [f"RMS err {s}" for s in states]
            + [f"max abs err {s} (unknown input)" for s in unknown]
            + ["rejected", "update p50 (us)", "replay speed (x real time)"])
    rows = [head, ["---"] * len(head)]
    for p in pairs:
        m = p.metrics
        label = f"{m['observer_type']} ({p.config.name})" if m else p.config.name
        if m is None:
            rows.append([p.bag.name, label, f"FAILED: {p.error}"] + [""] * (len(head) - 3))
            continue
        errs = (m.get("errors") or {}).get("per_state") or {}
        per = [errs.get(n) for n in m["state_names"]] + [None] * (len(states) - len(m["state_names"]))
        if m["errors"] is None:
            conv = "n/a (no truth)"
        elif m["convergence_time_s"] is None:
            conv = f"never (tol {m['tolerance']:g})"
        else:
            conv = _g(m["convergence_time_s"], 4)
        rej = m["samples_rejected"]
        if rej:
            rej = f"{rej} (" + ", ".join(f"{k}: {v}" for k, v in m["rejected_by_reason"].items()) + ")"
        rows.append(
            [p.bag.name, label,
             "none" if m["guaranteed_time_s"] is None else _g(m["guaranteed_time_s"], 4),
             conv, _g(m["settle_time_s"], 4)]
            + [_g(e["max_abs_after_settle"]) if e else "n/a" for e in per]
            + [_g(e["rms_after_settle"]) if e else "n/a" for e in per]
            + [_g(_unknown_input_errors(p)[u]["max_abs_after_settle"])
               if u in _unknown_input_errors(p) else "n/a" for u in unknown]
            + [str(rej), _g(m["update_time_us"]["p50"], 3),
               _g(m["replay_speed_x_realtime"], 3)])
    return "\n".join("| " + " | ".join(str(c) for c in row) + " |" for row in rows)


def joint_table(pairs: list[Pair]) -> str:
    """The table of per-joint replays (``joints``): each joint's velocity error, all joints'."""
    joints = list(dict.fromkeys(j for p in pairs if p.metrics for j in p.metrics.get("joints") or ()))
    head = (["bag", "observer (params)", "guaranteed time (s)", "settle (s)"]
            + [f"RMS err velocity {j}" for j in joints]
            + ["RMS err velocity (all joints)", "max abs err velocity (all joints)", "rejected",
               "update p50 (us)", "replay speed (x real time)"])
    rows = [head, ["---"] * len(head)]
    for p in pairs:
        m = p.metrics
        if m is None:
            rows.append([p.bag.name, p.config.name, f"FAILED: {p.error}"] + [""] * (len(head) - 3))
            continue
        je = m.get("joint_errors") or {}
        per = je.get("per_joint") or {}
        vel = [((per.get(j) or {}).get("per_state") or {}).get("velocity") for j in joints]
        overall = ((je.get("all_joints") or {}).get("per_state") or {}).get("velocity")
        rows.append(
            [p.bag.name, f"{m['observer_type']} ({p.config.name})",
             "none" if m["guaranteed_time_s"] is None else _g(m["guaranteed_time_s"], 4),
             _g(m["settle_time_s"], 4)]
            + [_g(v["rms_after_settle"]) if v else "n/a" for v in vel]
            + [_g(overall["rms_after_settle"]) if overall else "n/a",
               _g(overall["max_abs_after_settle"]) if overall else "n/a",
               str(m["samples_rejected"]), _g(m["update_time_us"]["p50"], 3),
               _g(m["replay_speed_x_realtime"], 3)])
    return "\n".join("| " + " | ".join(str(c) for c in row) + " |" for row in rows)


def _torque_table(pairs: list[Pair]) -> str | None:
    """The arm's external-torque table (cli/torque_table.py) of the replays of the arm's
    external-torque families among ``pairs``; printed as it is made."""
    from .torque_table import table as torque_table
    text = torque_table(pairs)
    if text:
        print("\n**arm7: external joint torques and collisions**\n\n" + text)
    return text


def markdown(pairs: list[Pair], notes: list[str], out: Path, torque: str | None = None) -> str:
    """The whole report.md."""
    lines = [REPORT_TITLE, "",
             "Every bag replayed offline through every observer with `fto-replay` "
             "(the same runner code path as the live node).", "", tables(pairs), ""]
    if torque:
        lines += ["**arm7: external joint torques and collisions** (the URDF's dynamics; "
                  "docs/external_torque.md)", "", torque, "",
                  "- *tau_ext*: the replays of config/arm7_external_torque.yaml and "
                  "config/arm7_momentum_observer.yaml (the families' unknown-input estimate) "
                  "against the bag's truth; *free motion*: from 0.5 s on, outside every contact "
                  "(and 0.3 s after it); *detection delay*: from each contact's start to the "
                  "first joint crossing its lower level (bound 1e-2 false alarms per hour, "
                  "calibrated over the first 2 s of estimates); *false alarms*: crossings "
                  "outside the contacts; *model-mismatch WARN*: the joints whose calibrated "
                  "residual is above 3x the encoder's noise.", ""]
    lines += [
             "- *guaranteed time*: the observer's guaranteed convergence time after a (re)start "
             "(none: asymptotic, or finite time without a computable bound).",
             "- *measured convergence*: first time after the observer's first sample from which "
             "the largest absolute error over all states stays below the tolerance to the end "
             "of the bag (never: it does not).",
             "- *max abs err*, *RMS err*: truth - estimate over the samples at least *settle* "
             "seconds after the observer's (re)start (the guaranteed time + 0.01 s, or 0.11 s "
             "without a guarantee, or the config's metrics.settle_time), in state units; "
             "*(unknown input)*: the same for the identified unknown input where the bag has "
             "its truth.",
             "- *RMS err velocity* (per-joint systems): each joint's published velocity against "
             "the truth JointState by name, after *settle*; *all joints*: every joint's errors "
             "pooled.",
             "- *update p50*: median runner time per sample (each window's one compiled "
             "`Runner.process_block` call over its samples: validation, observer update, "
             "outputs); *replay speed*: bag duration / wall time of the whole "
             "replay (read, runner, write), on the machine that made this report.", ""]
    if notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    lines += ["## Plots", ""]
    for p in pairs:
        if p.metrics and p.metrics.get("plot"):
            rel = f"{p.name}/{p.metrics['plot']}"
            lines += [f"### {p.bag.name} / {p.config.name}", "",
                      f"[{rel}]({rel}) - metrics: [{p.name}/metrics.json]({p.name}/metrics.json)",
                      "", f"![{p.name}]({rel})", ""]
        elif p.error:
            lines += [f"### {p.bag.name} / {p.config.name}", "", f"FAILED: {p.error}", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    from ..core.command_line import positive_int
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Replay the DC-motor bags (and the other example systems' bags) through every "
                    "available observer config and print side-by-side comparisons (also written "
                    "to OUT/report.md).")
    p.add_argument("--out", default="out", metavar="DIR",
                   help="output directory (default: out), replaced when it holds an earlier "
                        "report, refused when it holds anything else; each replay goes to "
                        "DIR/<bag>__<config>/")
    p.add_argument("--bags-dir", default="bags", metavar="DIR", help="bags directory (default: bags)")
    p.add_argument("--config-dir", default="config", metavar="DIR",
                   help="params files directory (default: config)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (replays done, rate, time left; shown on a terminal "
                        "whatever the number of workers)")
    p.add_argument("--workers", type=positive_int, default=None, metavar="N",
                   help="replays at once, each in a worker process (default: one per core; "
                        "1 replays one after the other in this process)")
    return p


def main(argv=None) -> int:
    from ..core.command_line import guarded
    return guarded(PROG, _main, build_parser().parse_args(argv))


def _said(p: Pair, progress=None) -> None:
    """The line on stderr when a pair is done (above the progress bar)."""
    from ..core.progress import say
    if p.error:
        say(progress, f"{PROG}: error: {p.bag.name} with {p.config.name}: {p.error}")
    else:
        say(progress, f"{PROG}: {p.bag.name} with {p.config.name}: done "
            f"({p.metrics['replay_speed_x_realtime']:.1f}x real time)")


def _main(args) -> int:
    from ..sweep.engine import Engine, Lost, prestart
    from ..core.progress import bar
    prestart(args.workers)                   # the workers' imports start now, beside ours
    from ..sweep.tasks import Run, bag_size, execute

    bags_dir, config_dir = Path(args.bags_dir), Path(args.config_dir)
    for d, what in ((bags_dir, "bags"), (config_dir, "config")):
        if not d.is_dir():
            print(f"{PROG}: error: {what} directory {d} does not exist (run from the repository "
                  f"root or pass --{what.split()[0]}-dir)", file=sys.stderr)
            return 1
    # an earlier report in OUT is replaced (that is what the main job does every time),
    # nothing else: checked before any work, removed once there is something to replay
    inputs = (bags_dir, config_dir)
    try:
        out = check_output(args.out, "report", overwrite=True, inputs=inputs)
    except OutputError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    pairs, notes = plan(bags_dir, config_dir)
    pairs += plan_examples(bags_dir, config_dir)
    for n in notes:
        print(f"{PROG}: note: {n}", file=sys.stderr)
    if not pairs:
        print(f"{PROG}: error: nothing to replay", file=sys.stderr)
        return 1
    try:
        create_output(out, "report", overwrite=True, inputs=inputs)
    except OutputError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    for p in pairs:
        p.out = out / p.name
        if not p.bag.exists():
            p.error = (f"bag {p.bag} is missing (make it with: fto-simulate {SYSTEM} "
                       f"--out {p.bag} ...)")
            _said(p)
    todo = [p for p in pairs if p.error is None]
    with Engine(workers=args.workers) as engine, \
            bar(len(todo), "replays", enabled=not args.no_progress) as progress:
        progress.set_postfix_str(f"on {engine.description}")
        runs = [Run(i, str(p.bag), tuple(map(str, p.params)), str(p.bag),
                    tuple(map(str, p.params)), out=str(p.out), plot=True)
                for i, p in enumerate(todo)]

        def done(i: int, outcome) -> None:
            if isinstance(outcome, Lost):
                todo[i].error = outcome.message
            else:
                todo[i].metrics, todo[i].error = outcome.metrics, outcome.error
            progress.update(1)
            _said(todo[i], progress)

        engine.map(execute, [(r,) for r in runs], costs=[bag_size(p.bag) for p in todo],
                   on_done=done)
    print(tables(pairs))
    torque = _torque_table(pairs)
    report = out / "report.md"
    try:
        report.write_text(markdown(pairs, notes, out, torque) + "\n")
    except OSError as err:
        what = abandon(out, "report", f"{err.strerror or err}", keep=True)
        print(f"{PROG}: error: cannot write {report}: {err.strerror or err}; {what}",
              file=sys.stderr)
        return 1
    failed = [p for p in pairs if p.error]
    print(f"\nwrote {report}" + (f"; {len(failed)} of {len(pairs)} replay(s) FAILED" if failed
                                  else f" ({len(pairs)} replays)"))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
