"""How long an arm model takes to configure, and how much memory, by the URDF's size: the
joint cap of fto_ros/arm/urdf.py (MAX_JOINTS) is chosen from this (issue 28, F16).

Per chain of n revolute joints (test/support/arm_urdfs.py's ``chain``), in a fresh process
each: the time to read the URDF, build the model (physics checks, the packed tree, the
default joint list) and evaluate its dynamics once (M(q), and the estimators' per-sample
terms M, Mdot, C' v, g), and the process's peak RSS, beside its RSS after the imports; then
the external-torque node's observer on it, built as the node builds it (``Runner`` on the
flat parameters: observer.type external_torque, robot_description, the URDF's default joint
list, T = 60 ms at 1 kHz: its ring holds M and Mdot of every sample, 2 n^2 (W + 1) values;
the runner's block loop compiled or loaded) and its first three samples (``set_input`` +
``process``). The compiled code comes from the numba cache (warm: an installed node's second
start); the first start's compilation, whatever n, is measured once with an empty cache.
Past 64 MiB of ring (external_torque.MAX_WINDOW_BYTES) the family refuses the window: that
row says so.

    PYTHONPATH=. python benchmarks/bench_urdf_size.py [--sizes 10,50,100,150,200,250,300,400,500]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import json, resource, sys, time
sys.path[:0] = [{root!r}, {support!r}]
import numpy as np
from arm_urdfs import chain
from fto_ros.arm.model import load_model
from fto_ros.arm import urdf
urdf.MAX_JOINTS = 10 ** 6                     # measure past the cap
text = chain({n})
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
t0 = time.perf_counter()
m = load_model(None, robot_description=text)
t1 = time.perf_counter()
q = np.linspace(-1, 1, m.n)
M = m.mass_matrix(q)
terms = m.momentum_terms(q, np.ones(m.n))
t2 = time.perf_counter()
t3 = time.perf_counter()
m.momentum_terms(q, np.ones(m.n))
t4 = time.perf_counter()
assert np.all(np.isfinite(M)) and m.n == {n}
model_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
out = dict(n={n}, build=t1 - t0, first=t2 - t1, again=t4 - t3, base_mb=base, model_mb=model_mb)
if {estimator}:
    from fto_ros.core.errors import ConfigError
    from fto_ros.runner.runner import Runner
    t5 = time.perf_counter()
    try:                                       # the node's default window, 60 ms at 1 kHz
        r = Runner({{"observer.type": "external_torque", "robot_description": text,
                    "joints": []}})
        u = np.zeros(r.observer.n_inputs)
        for k in range(3):
            r.set_input(1.0 + k * 1e-3, u)
            r.process(1.0 + k * 1e-3, q)
        out.update(estimator=time.perf_counter() - t5,
                   peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    except ConfigError as e:
        out.update(refused=str(e)[:100])
print(json.dumps(out))
"""


def measure(n: int, env: dict, estimator: bool = True) -> dict:
    code = CHILD.format(root=str(ROOT), support=str(ROOT / "test" / "support"), n=n,
                        estimator=estimator)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         timeout=1800)
    if res.returncode != 0:
        return dict(n=n, error=res.stderr.strip().splitlines()[-1][:120])
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="10,50,100,150,200,250,300,400,500")
    a = ap.parse_args(argv)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as cold:
        first = measure(10, dict(env, NUMBA_CACHE_DIR=cold), estimator=False)
        measure(10, env)                                   # fill the ordinary cache
        rows = [measure(int(n), env) for n in a.sizes.split(",")]
    load = Path("/proc/loadavg").read_text().split()[0]
    print(f"first start (empty numba cache), 10 joints: build + first evaluation "
          f"{first['build'] + first['first']:.2f} s (load {load})")
    print("| joints | build (s) | first M + terms (s) | model: build + first (s) | terms again "
          "(ms) | RSS after imports (MB) | model: peak - imports (MB) | + external_torque (Runner), 3 "
          "samples (s) | with it: peak - imports (MB) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['n']} | failed: {r['error']} |")
            continue
        print(f"| {r['n']} | {r['build']:.3f} | {r['first']:.3f} | {r['build'] + r['first']:.3f}"
              f" | {r['again'] * 1e3:.2f} | {r['base_mb']:.0f} | {r['model_mb'] - r['base_mb']:.0f}"
              + (f" | {r['estimator']:.3f} | {r['peak_mb'] - r['base_mb']:.0f} |" if "estimator"
                 in r else f" | refused: {r['refused']} | |"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
