"""Replays of the committed (bag, config) pairs logged call by call, and the reference they
are compared with (test/data/runner_reference.npz).

The reference was recorded once, before the per-sample work moved into compiled kernels
(main at d72ec3a, 2026-12-01), by running every pair of fto-report's plan (the DC motor)
and plan_examples (the papers' systems) through the replay and logging every call the
replay made into the runner: per pair the status of every call, every STRIDE-th output
(estimate, unknown-input estimate, convergence values) and the final counters.  A replay
of today's code is logged the same way (``log_replay``) and compared (``compare``).

A deliberate change of behaviour records the pairs it changes again, and only those:
``python test/support/reference_runs.py CONFIG_STEM ...`` (``regenerate``), said in the commit.
Recorded again so far: the luenberger and ekf pairs (except cubic_escape_ekf and
van_der_pol_ekf, unchanged), for their start from the first measurement (issue 19 item 18).
"""
from __future__ import annotations

import hashlib
import json
import tempfile
from pathlib import Path

import numpy as np

from fto_ros.replay.replay import replay
from fto_ros.runner import loop as L
from fto_ros.runner import runner as R

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "test" / "data" / "runner_reference.npz"


def load_reference():
    data = np.load(REFERENCE)
    meta = json.loads(str(data["meta"]))
    return data, meta


def log_replay(bag: Path, params: list[Path]):
    """(calls, results, runner) of a replay: every set_input / process / reject call, as
    the per-sample path made them; the replay's block calls (``process_block``) are logged
    row by row as those calls (an input row: set_input, a measurement: process, a refused
    row: reject), with the statuses and outputs the block returned."""
    log: list = []
    captured = {}
    cls = R.Runner
    orig = {k: getattr(cls, k) for k in ("process_block", "reject", "__init__")}

    def process_block(self, kind, t, values, refused=None):
        blk = orig["process_block"](self, kind, t, values, refused)
        _log_block(self, log, kind, t, values, refused, blk)
        return blk

    def reject(self, reason, *a, **k):
        log.append((2, 0.0, [], reason))
        return orig["reject"](self, reason, *a, **k)

    def init(self, *a, **k):
        orig["__init__"](self, *a, **k)
        captured["runner"] = self
    cls.process_block, cls.reject, cls.__init__ = process_block, reject, init
    try:
        with tempfile.TemporaryDirectory() as d:
            replay(bag, params, Path(d) / "o", plot=False, progress=False)
    finally:
        for k, v in orig.items():
            setattr(cls, k, v)
    return log, captured["runner"]


def _log_block(runner, log, kind, t, values, refused, blk) -> None:
    """The rows of one process_block call as the per-sample calls (see log_replay)."""
    obs = runner.observer
    m, p = obs.n_inputs, obs.n_outputs
    values = np.asarray(values, float).reshape(len(t), -1)
    r = blk.unknown_input.shape[2]
    for k in range(len(t)):
        st = int(blk.status[k, 0])
        why = R.reason(st)
        if kind[k] == L.REFUSED or (refused is not None and int(np.ravel(refused[k])[0]) > 0):
            log.append((2, 0.0, [], why))
        elif kind[k] == L.INPUT:
            log.append((0, float(t[k]), values[k, :m].tolist(), why))
        elif st != L.SKIPPED:
            out = why if st != L.OUTPUT else R.Output(
                float(t[k]), blk.estimate[k, 0].copy(),
                blk.unknown_input[k, 0].copy() if r and not np.isnan(blk.unknown_input[k, 0, 0])
                else None, blk.convergence[k, 0].copy(), None)
            log.append((1, float(t[k]), values[k, :p].tolist(), out))


def calls_hash(log) -> str:
    kinds = np.array([c[0] for c in log], np.int8)
    ts = np.array([c[1] for c in log])
    width = max([len(c[2]) for c in log] + [0])
    vals = np.full((len(log), width), np.nan)
    for i, c in enumerate(log):
        vals[i, :len(c[2])] = c[2]
    return hashlib.sha256(kinds.tobytes() + ts.tobytes()
                          + np.nan_to_num(vals, nan=1e300).tobytes()).hexdigest()[:16]


def outputs(log, stride: int):
    """(status names per call, every stride-th output's (estimate, ui, convergence))."""
    status, est, ui, conv = [], [], [], []
    nout = 0
    for c in log:
        r = c[3]
        if r is None:
            status.append("")
        elif isinstance(r, str):
            status.append(r)
        else:
            status.append("output")
            if nout % stride == 0:
                est.append(np.asarray(r.estimate, float))
                conv.append(np.asarray(r.convergence, float))
                ui.append(np.zeros(0) if r.unknown_input is None else np.asarray(r.unknown_input, float))
            nout += 1
    return status, np.array(est), np.array(ui), np.array(conv)


def regenerate(names: list[str]) -> list[str]:
    """Record the pairs whose config file is named in ``names`` (e.g. msd_ekf) again with
    today's code, in place in REFERENCE: a deliberate change of behaviour (say which and why
    in the commit).  Returns the keys of the pairs recorded."""
    data, meta = load_reference()
    arrays = {k: data[k] for k in data.files if k != "meta"}
    codes = dict(meta["reasons"])
    done = []
    for pair in meta["pairs"]:
        if Path(pair["params"][-1]).stem not in names:
            continue
        log, run = log_replay(ROOT / "bags" / pair["bag"], [ROOT / f for f in pair["params"]])
        status, est, ui, conv = outputs(log, meta["stride"])
        for s in status:
            if s not in ("", "output") and s not in codes:
                codes[s] = max(codes.values(), default=0) + 1
        key = pair["key"]
        arrays[key + "_status"] = np.array(
            [0 if s == "" else (-1 if s == "output" else codes[s]) for s in status], np.int16)
        arrays[key + "_est"], arrays[key + "_ui"], arrays[key + "_conv"] = est, ui, conv
        pair.update(calls=calls_hash(log), accepted=run.accepted, rejected=dict(run.rejected),
                    resets=dict(run.resets), rebases=run.rebases,
                    outputs=sum(s == "output" for s in status))
        done.append(key)
    meta["reasons"] = codes
    np.savez_compressed(REFERENCE, meta=json.dumps(meta), **arrays)
    return done


def add(bag: str, params: list[str]) -> list[str]:
    """Add the pair (bags/BAG, params files) to REFERENCE and record it with today's code: a
    family new to the package joins the golden master (say so in the commit)."""
    data, meta = load_reference()
    if any(p["bag"] == bag and p["params"] == params for p in meta["pairs"]):
        raise SystemExit(f"the pair {bag} {params} is recorded already")
    key = f"p{1 + max(int(p['key'][1:]) for p in meta['pairs'])}"
    meta["pairs"].append({"key": key, "bag": bag, "params": params})
    arrays = {k: data[k] for k in data.files if k != "meta"}
    np.savez_compressed(REFERENCE, meta=json.dumps(meta), **arrays)
    return [k for k in regenerate([Path(params[-1]).stem]) if k == key]


if __name__ == "__main__":
    # python test/support/reference_runs.py CONFIG_STEM...: record those pairs again (see regenerate)
    # python test/support/reference_runs.py --add BAG PARAMS...: a new pair (see add)
    import sys
    if sys.argv[1:2] == ["--add"]:
        print(" ".join(add(sys.argv[2], sys.argv[3:])))
    else:
        print(" ".join(regenerate(sys.argv[1:])))
