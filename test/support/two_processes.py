"""Determinism across processes: the same computation in two fresh interpreters, compared bit
for bit.  Twice in one process proves little (the same caches, the same hash seed, the same
compiled code already loaded); two processes each import, compile (or load the numba cache),
hash strings with their own seed (PYTHONHASHSEED is left random) and allocate anew, so an
output that depends on a set's order, an id, uninitialised memory or a cache's state
differs between them.

``run_twice("module:function", *args)`` calls ``function(*args)`` (JSON arguments) in two
subprocesses, one after the other, with test/support and ``path`` on sys.path; the function
returns ``{name: array}``; ``assert_bitwise_equal`` compares the two results' bytes.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SUPPORT = Path(__file__).resolve().parent

_CHILD = """
import importlib, json, sys
import numpy as np
sys.path[:0] = json.loads(sys.argv[1])
module, _, function = sys.argv[2].partition(":")
out = getattr(importlib.import_module(module), function)(*json.loads(sys.argv[3]))
np.savez(sys.argv[4], **out)
"""


def run_twice(target: str, *args, path: tuple[str | Path, ...] = (),
              timeout: float = 900) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``target`` ("module:function") called with ``args`` in two fresh processes."""
    paths = [str(SUPPORT), *map(str, path), str(ROOT)]
    env = dict(os.environ)
    env.pop("PYTHONHASHSEED", None)
    results = []
    with tempfile.TemporaryDirectory(prefix="fto_twice_") as tmp:
        for i in range(2):
            out = Path(tmp) / f"run{i}.npz"
            res = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(paths), target,
                                  json.dumps(args), str(out)],
                                 cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
            assert res.returncode == 0, f"{target} in process {i + 1}:\n{res.stderr[-3000:]}"
            with np.load(out) as data:
                results.append({k: data[k] for k in data.files})
    return results[0], results[1]


def assert_bitwise_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> int:
    """Every array of ``a`` equal to ``b``'s byte for byte (dtype, shape, bits: the sign of a
    zero, a NaN's payload); the number of values compared."""
    assert sorted(a) == sorted(b), (sorted(a), sorted(b))
    n = 0
    for key in sorted(a):
        x, y = a[key], b[key]
        assert x.dtype == y.dtype and x.shape == y.shape, (key, x.dtype, x.shape, y.dtype, y.shape)
        if x.tobytes() != y.tobytes():
            diff = np.flatnonzero(np.frombuffer(x.tobytes(), np.uint8) != np.frombuffer(y.tobytes(), np.uint8))
            raise AssertionError(f"{key}: the two processes differ (first differing byte {diff[0]} "
                                 f"of {x.nbytes})")
        n += x.size
    return n
