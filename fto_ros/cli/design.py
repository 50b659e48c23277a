"""``fto-design PARAMS...``: what the plant block derives, without running anything.

The params files without an ``observer.type`` (the plant file, shared I/O settings) are
merged in order into the plant; every file with an ``observer.type`` is a tuning file,
designed on its own with that plant (as ``--params-file plant --params-file tuning``).
Printed: the plant; which observer types apply and, in one line each, why the others do
not; per applicable type the derived matrices and forms and its paper's structural
figures; per tuning file the observer built from the derived parameters (guaranteed time
and its start-up diagnostics: noise gain, conditioning, gains, the paper's checks).

Exit codes: 0 done, 2 bad parameters or arguments (a plant outside the chosen observer's
class included), 1 any other failure.  ``FTO_DEBUG=1`` shows an unexpected traceback.

A per-joint plant (``joints`` with constants ``'name=[v1, ..., vJ]'``, config/arm7_plant.yaml)
is designed joint by joint (cli/design_joints.py): the first joint in full, then a joint
table of whatever differs (constants, derived matrices, figures, the tuning files' design
figures).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..core.command_line import guarded, one_line

PROG = "fto-design"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Show what the plant block of the params files derives for "
        "every observer type (which apply, the derived matrices and forms, the design figures "
        "of each tuning file), without running anything; for a per-joint plant ('joints', "
        "constants 'name=[v1, ..., vJ]'), per joint (the joint table).")
    p.add_argument("params", nargs="+", metavar="PARAMS",
                   help="params files: the plant file (and any shared settings) first, then "
                        "tuning files (files with observer.type), each designed on its own")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override one parameter of the plant (read as rcl reads -p NAME:=VALUE)")
    p.add_argument("--node-name", default=None, metavar="N",
                   help="node name selecting the params blocks (default observer_node)")
    p.add_argument("--suggest-from", default=None, metavar="BAG",
                   help="for every hosm tuning file: measure on this recording the derivative "
                        "hosm.M bounds and suggest M (docs/hosm.md)")
    return p


def design(paths: list[Path], overrides: dict, node_name: str | None, out,
           suggest_from: Path | None = None) -> int:
    """Print the design; returns the exit code (raises ConfigError for a bad plant)."""
    from ..core.errors import ConfigError
    from ..plant import resolve_plant
    from ..plant.design import (applicability_lines, classify, derivation_lines, needs_tuning,
                                observer_lines, plant_lines)
    from ..plant.derive import Derivation
    from ..runner import Runner
    from ..runner.params_file import load_params_file, load_params_files

    flats = [(p, load_params_file(p, node_name)) for p in paths]
    shared = [p for p, flat in flats if "observer.type" not in flat]
    tunings = [(p, flat) for p, flat in flats if "observer.type" in flat]
    if not shared:
        raise ConfigError("params file", "give the plant file first (a params file with the "
                          "plant block and no observer.type)")
    base = load_params_files(shared, node_name, overrides)
    if not any(k.startswith("plant.") for k in base):
        raise ConfigError("plant.states", f"no plant block in {', '.join(map(str, shared))}")
    joints = base.get("joints") or []
    if isinstance(joints, list) and joints and all(isinstance(j, str) for j in joints):
        from .design_joints import design_joints
        return design_joints(base, tunings, joints, out, PROG)
    plant = resolve_plant(base)

    def section(type_name: str, flat=base) -> dict:
        return {k[len(type_name) + 1:]: v for k, v in flat.items() if k.startswith(type_name + ".")}

    results = classify(plant, section)
    lines = plant_lines(plant) + applicability_lines(results)
    for type_name, r in results.items():
        if isinstance(r, Derivation):
            lines += derivation_lines(type_name, r, plant)
    print("\n".join(lines), file=out)
    rc = 0
    for path, flat in tunings:
        merged = {**base, **flat}
        type_name = flat["observer.type"]
        label = f"{type_name} ({path.name})"
        try:
            r = results.get(type_name)
            if isinstance(r, ConfigError) and needs_tuning(r, type_name):
                from ..plant import derive
                d = derive(type_name, plant, section(type_name, merged))
                print("\n".join(derivation_lines(type_name, d, plant, f" and {path.name}")),
                      file=out)
            obs = Runner(merged).observer
        except ConfigError as exc:
            print(f"{PROG}: error: {path}: {exc}", file=sys.stderr)
            rc = 2
            continue
        print("\n".join(observer_lines(label, obs)), file=out)
        if suggest_from is not None:
            from .suggest import suggest_m
            lines = suggest_m(merged, suggest_from, node_name) if type_name == "hosm" else \
                [f"  --suggest-from: {type_name} has no M to suggest (hosm only)"]
            print("\n".join(lines), file=out)
    return rc


def main(argv=None) -> int:
    return guarded(PROG, _main, build_parser().parse_args(argv))


def _main(args: argparse.Namespace) -> int:
    from ..bag import BagError
    from ..core.errors import ConfigError
    from ..runner.params_file import parse_override
    try:
        overrides = dict(parse_override(text) for text in args.set)
        bag = Path(args.suggest_from) if args.suggest_from else None
        return design([Path(p) for p in args.params], overrides, args.node_name, sys.stdout, bag)
    except ConfigError as err:
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 2
    except BagError as err:                        # --suggest-from: a bag it cannot read
        print(f"{PROG}: error: {one_line(err)}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
