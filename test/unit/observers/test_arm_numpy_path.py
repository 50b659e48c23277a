"""The arm families' compiled kernels against their numpy path (FTO_ROS_NUMBA=0: the same
kernel code run as Python over the same arrays), through the runner, on a stream that
visits every branch a real arm's stream does: jittered stamps (+-50 us), encoder noise, a
lost message the family bridges, a gap the runner restarts at, the calibration, a contact
that crosses both levels, a payload set at run time (the window's history evaluated
again), the latched collision cleared. Every output of every call (estimate, tau_ext, the
convergence values with the contact and collision flags and levels) and every status is
the same, bit for bit: the kernels add, multiply and call tanh / sqrt in one order on both
paths, and numba compiles without fast-math (no reassociation, no fused multiply-add).
external_torque, momentum_observer. ROS-free."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from arm_families import ROOT

#: the stream and the run, in a fresh interpreter (the numba switch is read at import)
_RUN = """
import sys, json, numpy as np
sys.path.insert(0, 'test/support')
from arm_families import ARM7, ARM7_JOINTS, runner
from fto_ros.arm import load_model
from fto_ros.models.arm import ArmSettings, Contact, simulate_arm
fam = {family!r}
model = load_model(ARM7_JOINTS, urdf=ARM7)
r = simulate_arm(model, ArmSettings(duration=0.5, jitter=5e-5, seed=4,
                 contacts=[Contact("link_4", 0.25, 0.1, (0, 150, 0))]))
extra = (dict(external_torque__window=0.02) if fam == "external_torque"
         else dict(momentum_observer__gain=100.0))
run = runner(fam, ARM7, joints=ARM7_JOINTS, collision__calibration=0.06, **extra)
keep = np.ones(r.t.size, bool)
keep[140] = False                         # one lost message: bridged
keep[380:395] = False                     # 16 ms: the runner restarts
t, y, u = r.t[keep], r.q_measured[keep], r.tau[keep]
rows, cleared = [], None
for k in range(len(t)):
    if k == 300:
        run.observer.set_payload({{"payload.frame": "link_7", "payload.mass": 0.5}})
    if k == 340:
        cleared = run.observer.reset_collision()
    run.set_input(float(t[k]), u[k])
    o = run.process(float(t[k]), y[k])
    rows.append(o if isinstance(o, str) else     # NaN (no estimate yet) as a string
                [x if x == x else "nan" for x in
                 np.concatenate([o.estimate, o.unknown_input, o.convergence]).tolist()])
fields = list(run.convergence_fields)
print(json.dumps(dict(rows=rows, cleared=cleared, fields=fields, resets=dict(run.resets),
                      bridged=run.observer.diagnostics()["gaps bridged"])))
"""


def _run(family: str, numba: str) -> dict:
    env = dict(os.environ, FTO_ROS_NUMBA=numba)
    res = subprocess.run([sys.executable, "-c", _RUN.format(family=family)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.splitlines()[-1])


@pytest.mark.parametrize("family", ["external_torque", "momentum_observer"])
def test_the_numpy_path_equals_the_compiled_kernel_bit_for_bit(family):
    from fto_ros.core import jit
    if not jit.ENABLED:
        pytest.skip("numba is off in this run: the compiled side cannot be compared")
    compiled, python = _run(family, "1"), _run(family, "0")
    # the stream visited what it was built for (on the compiled side)
    assert compiled["bridged"] == "1" and compiled["resets"] == {"gap": 1}
    fields = compiled["fields"]
    out = np.array([[np.nan if x == "nan" else x for x in r] for r in compiled["rows"]
                    if not isinstance(r, str)])
    conv = out[:, -len(fields):]
    assert conv[:, fields.index("calibrated")].max() == 1.0
    collided = [f for f in fields if f.startswith("collision.") and conv[:, fields.index(f)].max()]
    assert collided and compiled["cleared"] >= 1, (collided, compiled["cleared"])
    # and the numpy path did the same, to the last bit
    first = next((k for k, (a, b) in enumerate(zip(python["rows"], compiled["rows"]))
                  if a != b), None)
    assert first is None and len(python["rows"]) == len(compiled["rows"]), (
        f"call {first}: numpy {python['rows'][first]} compiled {compiled['rows'][first]}")
    assert (python["cleared"], python["resets"], python["bridged"]) == \
        (compiled["cleared"], compiled["resets"], compiled["bridged"])
