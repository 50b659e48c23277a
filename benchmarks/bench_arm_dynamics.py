"""Per-sample cost of an arm's dynamics terms: the compiled dynamics (fto_ros/arm/dynamics.py)
against Pinocchio's calls as the estimators made them before (crba, computeCoriolisMatrix,
computeGeneralizedGravity, then M's lower triangle, C + C^T and C^T v), measured in one run,
interleaved (A B A B ...) so that the machine's load weighs on both alike.

Rows, per arm (urdf/arm7.urdf; the Panda-class arm with a mimic gripper if committed):
- the terms the window estimator takes twice per sample (M, Mdot, C^T v, g; and without M);
- the whole window estimator's sample (``WindowEstimator.update``, T = 60 ms, compiled steps)
  with the model's terms from each.
Positions and velocities of bags/arm7_contact_link6 (arm7) or a smooth trajectory.

    PYTHONPATH=. python benchmarks/bench_arm_dynamics.py [--samples 3000] [--rounds 5]
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fto_ros.arm.external_torque import WindowEstimator  # noqa: E402
from fto_ros.arm.model import load_model  # noqa: E402


class PinocchioTerms:
    """The estimators' per-sample terms as computed before the compiled dynamics: Pinocchio's
    model, its joints not listed locked where the model puts them (buildReducedModel, as
    every unlisted joint had to be locked then)."""

    def __init__(self, model, text: str):
        import pinocchio as pin
        full = pin.buildModelFromXML(text)
        qf, _ = model.full_state(np.zeros(model.n))
        q0 = pin.neutral(full)
        lock = []
        for name, x in zip(model.moving_joints, qf):
            if name not in model.joints:
                j = full.getJointId(name)
                q0[full.joints[j].idx_q] = x
                lock.append(j)
        self.pin, self.pm = pin, pin.buildReducedModel(full, lock, q0) if lock else full
        if [self.pm.names[i] for i in range(1, self.pm.njoints)] != list(model.joints):
            raise SystemExit("the listed joints are not Pinocchio's tree order")
        self.pm.armature = np.asarray(model.armature, dtype=float)
        self.data = self.pm.createData()
        self.lower = np.tril_indices(model.n, -1)
        self.qp = pin.neutral(self.pm)
        self.kinds = [self.pm.joints[i].nq for i in range(1, self.pm.njoints)]

    def configuration(self, q):
        out, k = self.qp, 0
        for nq, x in zip(self.kinds, q):
            if nq == 2:
                out[k], out[k + 1] = math.cos(x), math.sin(x)
            else:
                out[k] = x
            k += nq
        return out

    def momentum_terms(self, q, v, mass=True, passive=None):
        pin, pm, data = self.pin, self.pm, self.data
        qp = self.configuration(q)
        M = None
        if mass:
            M = np.array(pin.crba(pm, data, qp))
            M[self.lower] = M.T[self.lower]
        C = np.array(pin.computeCoriolisMatrix(pm, data, qp, v))
        g = np.array(pin.computeGeneralizedGravity(pm, data, qp))
        return M, C + C.T, C.T @ v, g


def per_sample(f, ks) -> float:
    t0 = time.perf_counter()
    for k in ks:
        f(k)
    return (time.perf_counter() - t0) / len(ks) * 1e6


def arms():
    out = []
    from fto_ros.cli.simulate_arm import read_arm_bag
    run, _ = read_arm_bag(ROOT / "bags" / "arm7_contact_link6")
    text = (ROOT / "urdf" / "arm7.urdf").read_text()
    out.append(("arm7 (7 joints)", text, None, run.q_measured, run.v, run.tau))
    panda = ROOT / "urdf" / "panda_gripper.urdf"
    if panda.exists():
        text = panda.read_text()
        m = load_model(None, robot_description=text)
        t = np.arange(10000) * 1e-3
        q = 0.4 * np.sin(np.outer(t, np.linspace(0.5, 1.5, m.n)))
        v = 0.4 * np.cos(np.outer(t, np.linspace(0.5, 1.5, m.n))) * np.linspace(0.5, 1.5, m.n)
        out.append(("panda_gripper (7 listed, finger passive, mimic)", text, None, q, v,
                    np.zeros_like(q)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args(argv)
    ks = np.arange(2000, 2000 + a.samples)
    print(f"per sample (us), median of {a.rounds} interleaved rounds of {a.samples} samples; "
          f"load {Path('/proc/loadavg').read_text().split()[0]}")
    print("| arm | what | Pinocchio (before) | compiled (after) | before / after |")
    print("|---|---|---|---|---|")
    for name, text, joints, q, v, tau in arms():
        model = load_model(joints, robot_description=text)
        ref = PinocchioTerms(model, text)
        for x, y in zip(ref.momentum_terms(q[2000], v[2000]),
                        model.momentum_terms(q[2000], v[2000])):
            if not np.allclose(x, y, rtol=0, atol=1e-10 * np.abs(x).max()):
                raise SystemExit(f"{name}: the two sides' terms differ")
        ests = {}
        for side, terms in (("before", ref.momentum_terms), ("after", model.momentum_terms)):
            est = WindowEstimator(model)
            est.model = _Swap(model, terms)
            for k in range(1000, 1100):        # fill the window, compile
                est.update(k * 1e-3, q[k], tau[k])
            ests[side] = est
        calls = {"before": ref.momentum_terms, "after": model.momentum_terms}
        cases = {"M, Mdot, C'v, g": lambda f: (lambda k: f(q[k], v[k])),
                 "Mdot, C'v, g (no M)": lambda f: (lambda k: f(q[k], v[k], False)),
                 "window estimator, whole sample": None}
        for what, make in cases.items():
            times = {"before": [], "after": []}
            for _ in range(a.rounds):
                for s in ("before", "after"):
                    if make is None:            # a fresh window, then the timed stream
                        e = ests[s]
                        e.reset()
                        for k in range(ks[0] - 62, ks[0]):
                            e.update(k * 1e-3, q[k], tau[k])
                        f = (lambda k, e=e: e.update(k * 1e-3, q[k], tau[k]))
                    else:
                        f = make(calls[s])
                        f(ks[0])
                    times[s].append(per_sample(f, ks))
            b, c = statistics.median(times["before"]), statistics.median(times["after"])
            print(f"| {name} | {what} | {b:.1f} | {c:.1f} | {b / c:.2f} |")
    return 0


class _Swap:
    """The model with its momentum_terms replaced (the estimator's only per-sample call)."""

    def __init__(self, model, terms):
        self._model, self.momentum_terms = model, terms

    def __getattr__(self, name):
        return getattr(self._model, name)


if __name__ == "__main__":
    sys.exit(main())
