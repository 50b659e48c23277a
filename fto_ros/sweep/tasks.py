"""One run of a sweep (or of the main job), as a worker executes it: a replay through the
harness's code path (:func:`fto_ros.replay.replay`) whose failure is a value.

A :class:`Run` names its bag and params files by absolute path (*shared* data: the worker
reads the same path, on this machine or on storage every worker mounts).  For a cluster
without shared storage the client reads the files once (:func:`read_files`), the engine
sends them to the workers, and each worker process writes them once into a private
temporary directory (:func:`materialize`) removed when that process exits (*send* data).
"""
from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.command_line import one_line
from .engine import where

#: outcome kinds of a failed run: a parameter refused, a bad bag, anything else
CONFIG, BAG, RUNTIME = "config", "bag", "runtime"


@dataclass(frozen=True)
class Run:
    """What one run needs; ``bag`` and ``params`` are as the user gave them (the rows show
    them), ``bag_path`` and ``params_paths`` absolute (what the worker opens)."""

    index: int
    bag: str
    params: tuple[str, ...]
    bag_path: str
    params_paths: tuple[str, ...]
    overrides: dict[str, Any] = field(default_factory=dict)
    #: keep the run's output bag and metrics.json here; None: a temporary directory
    out: str | None = None
    node_name: str | None = None
    tolerance: float | None = None
    after: float | None = None
    plot: bool = False                # write replay.png beside metrics.json
    progress: bool = False            # a progress bar on a terminal (in this process only)
    #: return only the figures a sweep's row needs (:func:`brief`), not the whole metrics:
    #: a sweep of 100 000 runs keeps 100 000 of them in memory
    brief: bool = False


@dataclass
class Outcome:
    """What a run gives back: the replay's metrics, or its error (one line) and kind."""

    index: int
    metrics: dict[str, Any] | None = None
    error: str | None = None
    kind: str | None = None
    worker: str = ""
    wall_s: float = 0.0
    cpu_s: float = 0.0                # CPU time of the worker process for this run


#: the metrics a sweep's row reads (the rest stays in the run's metrics.json)
BRIEF_KEYS = ("observer_type", "convergence_time_s", "samples_rejected", "restarts",
              "guaranteed_time_s", "settle_time_s", "replay_speed_x_realtime")


def brief(metrics: dict[str, Any]) -> dict[str, Any]:
    """The part of a replay's metrics a sweep's row needs: BRIEF_KEYS, and per state the
    RMS and largest absolute error after the settle time."""
    out = {k: metrics[k] for k in BRIEF_KEYS}
    per_state = (metrics.get("errors") or {}).get("per_state")
    out["errors"] = None if per_state is None else {"per_state": {
        name: {k: e[k] for k in ("rms_after_settle", "max_abs_after_settle")}
        for name, e in per_state.items()}}
    return out


def classify(err: BaseException) -> tuple[str, str]:
    """(kind, one-line message) of a replay's exception."""
    from ..bag import BagError
    from ..core.errors import ConfigError
    from ..replay import ReplayError
    if isinstance(err, ConfigError):
        return CONFIG, one_line(err)
    if isinstance(err, (BagError, ReplayError)):
        return BAG, one_line(err)
    if isinstance(err, OSError):
        return RUNTIME, one_line(err)
    return RUNTIME, f"unexpected {type(err).__name__}: {one_line(err)}"


def execute(run: Run, bag_files: "Files | None" = None,
            params_files: "tuple[Files, ...] | None" = None) -> Outcome:
    """Replay ``run``; never raises (a failure is the Outcome's error)."""
    from ..replay import DEFAULT_TOLERANCE, replay
    t0, c0 = time.perf_counter(), time.process_time()
    outcome = Outcome(run.index, worker=where())
    scratch = None
    try:
        bag = materialize(bag_files) if bag_files is not None else run.bag_path
        params = ([materialize(f) for f in params_files] if params_files is not None
                  else list(run.params_paths))
        if run.out is None:
            scratch = tempfile.mkdtemp(prefix="fto-sweep-run-")
            out = os.path.join(scratch, "out")
        else:
            out = run.out
        metrics = replay(
            bag, params, out, node_name=run.node_name, overwrite=True, progress=run.progress,
            after=run.after, plot=run.plot, overrides=run.overrides,
            tolerance=DEFAULT_TOLERANCE if run.tolerance is None else run.tolerance)
        outcome.metrics = brief(metrics) if run.brief else metrics
    except Exception as err:  # noqa: BLE001  a failed run is a row, not the end of the sweep
        outcome.kind, outcome.error = classify(err)
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    outcome.wall_s = time.perf_counter() - t0
    outcome.cpu_s = time.process_time() - c0
    return outcome


def bag_size(path: str | Path) -> int:
    """Bytes of a bag: what replaying it costs, roughly (the engine starts long runs first)."""
    p = Path(path)
    if p.is_file():
        return p.stat().st_size
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() else 0


# --------------------------------------------------------------------- sending the data
@dataclass(frozen=True)
class Files:
    """A bag (directory or .mcap file) or a params file, read into memory to be sent."""

    name: str
    digest: str
    contents: tuple[tuple[str, bytes], ...]   # (path relative to the parent of `name`, bytes)


def read_files(path: str | Path) -> Files:
    """The files of ``path`` (a file, or every file under a directory)."""
    p = Path(path)
    files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
    contents = tuple((str(f.relative_to(p.parent)), f.read_bytes()) for f in files)
    h = hashlib.sha256()
    for rel, data in contents:
        h.update(rel.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    return Files(p.name, h.hexdigest()[:16], contents)


_written: dict[str, str] = {}   # digest -> path, in this worker process
_scratch_root: list[str] = []


def materialize(files: Files) -> str:
    """The path of ``files`` on this worker: written once per process, removed at exit."""
    path = _written.get(files.digest)
    if path is not None and os.path.exists(path):
        return path
    if not _scratch_root:
        _scratch_root.append(tempfile.mkdtemp(prefix="fto-sweep-data-"))
        atexit.register(shutil.rmtree, _scratch_root[0], True)
    base = os.path.join(_scratch_root[0], files.digest)
    for rel, data in files.contents:
        target = os.path.join(base, rel)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        with open(target, "wb") as f:
            f.write(data)
    path = _written[files.digest] = os.path.join(base, files.name)
    return path
