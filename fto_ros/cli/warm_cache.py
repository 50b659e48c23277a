"""``fto-warm-cache [TUNING.yaml ...]``: build the compiled cache once, so that a deployment
can then only read it (``FTO_ROS_CACHE_MODE=readonly``; docs/security.md).

Builds the runner of every tuning file given (each with its system's plant file, as
fto-report runs it: runner/plant_files.py), or of every committed config when none is
given, with the cache writable whatever ``FTO_ROS_CACHE_MODE`` says: every generated model
module and every kernel it compiles are written into the private cache folder
(``FTO_ROS_CACHE``, else ``$XDG_CACHE_HOME/fto_ros``, else ``~/.cache/fto_ros``).  Run it at
install time, or once as the user the nodes run as; afterwards the nodes and tools, started
with ``FTO_ROS_CACHE_MODE=readonly``, read it and write nothing.

Exit codes: 0 every config built, 1 one failed (its line says why), 2 bad arguments or a
cache folder that is refused (shared, foreign, not writable) or not there.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

PROG = "fto-warm-cache"


def default_config_dir() -> Path:
    """The committed configs: beside the package's sources, else the installed share/."""
    here = Path(__file__).resolve().parents[2] / "config"
    return here if here.is_dir() else Path(sys.prefix) / "share" / "fto_ros" / "config"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Compile the kernels of the given "
                                "tuning files (default: every committed config) into the "
                                "private compiled cache, for a deployment that only reads it "
                                "(FTO_ROS_CACHE_MODE=readonly).")
    p.add_argument("tuning", nargs="*", metavar="TUNING.yaml",
                   help="tuning files (each run with its system's plant file); default: every "
                        "config in --config-dir")
    p.add_argument("--config-dir", type=Path, default=None, metavar="DIR",
                   help="where the committed configs are (default: the package's config/)")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    # this command writes the cache, whatever the environment says the others may do
    os.environ["FTO_ROS_CACHE_MODE"] = "readwrite"
    from ..core import private_cache as PC
    PC.reset()
    from ..core import jit
    from ..core.command_line import one_line
    from ..runner import Runner
    from ..runner.params_file import load_params_files
    from ..runner.plant_files import is_plant_file, params_files
    if not jit.ENABLED:
        print(f"{PROG}: error: numba is off (FTO_ROS_NUMBA=0 or not installed): nothing to "
              "compile", file=sys.stderr)
        return 2
    models = PC.folder("models")
    if models is None or not jit.caching():
        print(f"{PROG}: error: no usable private cache folder (the line above says why)",
              file=sys.stderr)
        return 2
    tunings = [Path(t) for t in args.tuning] or [
        p for p in sorted((args.config_dir or default_config_dir()).glob("*.yaml"))
        if not is_plant_file(p)]
    if not tunings:
        print(f"{PROG}: error: no tuning files", file=sys.stderr)
        return 2
    failed, t0 = 0, time.perf_counter()
    for path in tunings:
        try:
            Runner(load_params_files(params_files(path)))
        except Exception as err:  # noqa: BLE001  one config's failure is its line
            failed += 1
            print(f"{PROG}: {path}: FAILED: {type(err).__name__}: {one_line(err)}",
                  file=sys.stderr)
    print(f"{PROG}: {len(tunings) - failed} of {len(tunings)} config(s) built in "
          f"{time.perf_counter() - t0:.1f} s; {jit.compile_report() or 'nothing compiled'}; "
          f"cache: {PC.root()}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
