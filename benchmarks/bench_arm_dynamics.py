"""Per-sample cost of an arm's dynamics terms: the compiled dynamics (fto_ros/arm/dynamics.py)
against Pinocchio's calls as the estimators made them before (crba, computeCoriolisMatrix,
computeGeneralizedGravity, then M's lower triangle, C + C^T and C^T v), measured in one run,
interleaved (A B A B ...) so that the machine's load weighs on both alike.

Rows, per arm (urdf/arm7.urdf; the Panda-class arm with a mimic gripper if committed):
- the terms the window estimator takes twice per sample (M, Mdot, C^T v, g; and without M),
  from each side;
- the whole sample of each arm family (external_torque, T = 60 ms; momentum_observer,
  K = 50/s), built by ``Runner`` from the node's parameters, its kernel calling the compiled
  terms (Pinocchio cannot stand in there): through the node's call (the JointState intake,
  ``set_input`` + ``process``) and as one ``process_block`` (the replay's call).
Positions and velocities of bags/arm7_contact_link6 (arm7) or a smooth trajectory (efforts:
the bag's, or the model's gravity torque).

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

from benchmarks.arm_runs import arm_runner  # noqa: E402
from fto_ros.arm.model import load_model  # noqa: E402
from fto_ros.runner import loop as L  # noqa: E402


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
    from fto_ros.cli.arm_bag import read_arm_bag
    run, _ = read_arm_bag(ROOT / "bags" / "arm7_contact_link6")
    text = (ROOT / "urdf" / "arm7.urdf").read_text()
    out.append(("arm7 (7 joints)", text, list(run.names), run.q_measured, run.v, run.tau))
    panda = ROOT / "urdf" / "panda_gripper.urdf"
    if panda.exists():
        text = panda.read_text()
        m = load_model(None, robot_description=text)
        t = np.arange(10000) * 1e-3
        q = 0.4 * np.sin(np.outer(t, np.linspace(0.5, 1.5, m.n)))
        v = 0.4 * np.cos(np.outer(t, np.linspace(0.5, 1.5, m.n))) * np.linspace(0.5, 1.5, m.n)
        tau = np.array([m.gravity(x) for x in q])
        out.append(("panda_gripper (7 listed, finger passive, mimic)", text, list(m.joints),
                    q, v, tau))
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
    samples = []
    for name, text, joints, q, v, tau in arms():
        model = load_model(joints, robot_description=text)
        ref = PinocchioTerms(model, text)
        for x, y in zip(ref.momentum_terms(q[2000], v[2000]),
                        model.momentum_terms(q[2000], v[2000])):
            if not np.allclose(x, y, rtol=0, atol=1e-10 * np.abs(x).max()):
                raise SystemExit(f"{name}: the two sides' terms differ")
        calls = {"before": ref.momentum_terms, "after": model.momentum_terms}
        cases = {"M, Mdot, C'v, g": lambda f: (lambda k: f(q[k], v[k])),
                 "Mdot, C'v, g (no M)": lambda f: (lambda k: f(q[k], v[k], False))}
        for what, make in cases.items():
            times = {"before": [], "after": []}
            for _ in range(a.rounds):
                for s in ("before", "after"):
                    f = make(calls[s])
                    f(ks[0])
                    times[s].append(per_sample(f, ks))
            b, c = statistics.median(times["before"]), statistics.median(times["after"])
            print(f"| {name} | {what} | {b:.1f} | {c:.1f} | {b / c:.2f} |")
        samples.append((name, text, joints, q, tau))
    print(f"\nthe families' whole sample (us), median of {a.rounds} rounds of {a.samples} "
          "samples, compiled terms")
    print("| arm | family | node's call: intake, set_input + process | replay's call: "
          "process_block | node / block |")
    print("|---|---|---|---|---|")
    for name, text, joints, q, tau in samples:
        for family, params in FAMILIES.items():
            node, block = [], []
            for _ in range(a.rounds):
                node.append(node_call(family, params, text, joints, q, tau, ks))
                block.append(block_call(family, params, text, joints, q, tau, ks))
            b, c = statistics.median(node), statistics.median(block)
            print(f"| {name} | {family} | {b:.1f} | {c:.1f} | {b / c:.2f} |")
    return 0


FAMILIES = {"external_torque": {"external_torque__window": 0.06},
            "momentum_observer": {"momentum_observer__gain": 50.0}}


def _runner(family, params, text, joints, q, tau, ks):
    """The family's runner, fed the 1000 samples before ``ks`` (the window full)."""
    r = arm_runner(family, joints, text=text, **params)
    take, names = r.intake.take, list(joints)
    for k in range(ks[0] - 1000, ks[0]):
        y, u = take(names, q[k], tau[k])
        r.set_input(k * 1e-3, u)
        r.process(k * 1e-3, y)
    return r


def node_call(family, params, text, joints, q, tau, ks) -> float:
    r = _runner(family, params, text, joints, q, tau, ks)
    take, names = r.intake.take, list(joints)

    def one(k):
        y, u = take(names, q[k], tau[k])
        r.set_input(k * 1e-3, u)
        r.process(k * 1e-3, y)
    return per_sample(one, ks)


def block_call(family, params, text, joints, q, tau, ks) -> float:
    r = _runner(family, params, text, joints, q, tau, ks)
    take, names = r.intake.take, list(joints)
    width = max(r.observer.n_inputs, r.observer.n_outputs)
    kind = np.tile(np.array([L.INPUT, L.PAIRED], np.int8), len(ks))
    t = np.repeat(ks * 1e-3, 2)
    values = np.zeros((2 * len(ks), width))
    for i, k in enumerate(ks):
        y, u = take(names, q[k], tau[k])
        values[2 * i, :u.size], values[2 * i + 1, :y.size] = u, y
    t0 = time.perf_counter()
    blk = r.process_block(kind, t, values)
    us = (time.perf_counter() - t0) / len(ks) * 1e6
    if not np.all(blk.status[1::2, 0] == L.OUTPUT):
        raise SystemExit(f"{family}: not every sample gave an output")
    return us


if __name__ == "__main__":
    sys.exit(main())
