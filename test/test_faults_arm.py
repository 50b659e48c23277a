"""Fault injection into the arm's new inputs (fto_ros.arm): junk URDF sources, and per-joint
junk values and junk stamps into every external-torque estimator. A refused source is one
ConfigError; a junk sample raises SampleRejected and leaves the estimator exactly as a twin
that never saw it (bit for bit). Families and counts as the other fault suites (faultkit)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from faultkit import COUNTS, junk_stamps, junk_values
from fto_ros.core.errors import ConfigError
from fto_ros.models.arm import ArmSettings, simulate_arm
from fto_ros.arm import load_model
from fto_ros.arm.external_torque import (FiniteDifference, MomentumObserver, SampleRejected,
                                           WindowEstimator)

ROOT = Path(__file__).resolve().parents[1]
URDF = (ROOT / "urdf" / "arm7.urdf").read_text()
JOINTS = [f"joint_a{i}" for i in range(1, 8)]


def junk_urdf(rng: np.random.Generator) -> tuple[str, str]:
    """(family, text): the real URDF truncated, corrupted, with hostile XML, or fragments."""
    fam = ["truncated", "corrupted", "hostile", "fragments", "numbers"][rng.integers(5)]
    if fam == "truncated":
        return fam, URDF[:int(rng.integers(1, len(URDF) - 10))]
    if fam == "corrupted":
        chars = list(URDF)
        for i in rng.integers(0, len(chars), size=int(rng.integers(1, 20))):
            chars[i] = chr(int(rng.choice([0x3C, 0x3E, 0x22, 0x26, 0x20, 0xDCFF, 0xFFFE, 0x7F])))
        return fam, "".join(chars)
    if fam == "hostile":
        return fam, ['<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;">'
                     '<!ENTITY c "&b;&b;&b;&b;&b;&b;">]><robot name="&c;"/>',
                     '<?xml version="1.0"?><!DOCTYPE r SYSTEM "file:///etc/passwd"><robot/>',
                     "<robot>" * 5000, "\x00<robot/>", "<robot name='x'>\udcff</robot>"][
            rng.integers(5)]
    if fam == "fragments":
        pieces = ["<robot name='x'>", "</robot>", "<link name='a'/>", "<joint name='j'",
                  " type='revolute'>", "<parent link='a'/>", "<child link='b'/>", "&amp;", "]]>"]
        return fam, "".join(rng.choice(pieces, size=int(rng.integers(1, 9))))
    bad = ["nan", "inf", "-1", "1e400", "abc", ""][rng.integers(6)]
    attr = ["value", "ixx", "izz", "lower", "effort", "xyz"][rng.integers(6)]
    return fam, URDF.replace(f'{attr}="', f'{attr}="{bad} ', 1)


def test_junk_urdf_sources_are_refused_in_one_line():
    rng = np.random.default_rng(11)
    for _ in range(150):
        fam, text = junk_urdf(rng)
        COUNTS[f"arm_urdf_{fam}"] += 1
        try:
            model = load_model(JOINTS, robot_description=text)
        except ConfigError as err:
            assert "\n" not in str(err) and err.parameter in ("robot_description", "plant.joints")
            continue
        # what Pinocchio accepts must still be an arm with finite dynamics
        assert np.all(np.isfinite(model.mass_matrix(np.zeros(7))))


@pytest.fixture(scope="module")
def stream():
    return simulate_arm(load_model(JOINTS, robot_description=URDF),
                        ArmSettings(duration=0.06, seed=9))


@pytest.mark.parametrize("make", [
    lambda m: WindowEstimator(m, window=0.01),
    lambda m: MomentumObserver(m, gain=20.0),
    lambda m: MomentumObserver(m, gain=20.0, velocity="differentiator"),
    lambda m: FiniteDifference(m, 1e-3),
], ids=["window", "gmo_difference", "gmo_differentiator", "finite_difference"])
def test_junk_samples_are_rejected_and_leave_no_trace(stream, make):
    model = load_model(JOINTS, robot_description=URDF)
    r = stream
    clean, dirty = make(model), make(model)
    rng = np.random.default_rng(5)
    for k in range(r.t.size):
        if k:
            for _ in range(3):
                q, tau, t = r.q_measured[k].copy(), r.tau[k].copy(), r.t[k]
                what = rng.integers(3)
                if what == 0:                               # one joint, or the whole vector
                    fam, bad = junk_values(1 if rng.random() < 0.5 else 7, rng)
                    if isinstance(bad, list) and len(bad) == 1 and \
                            isinstance(bad[0], float):
                        q[int(rng.integers(7))] = bad[0]
                        fam = f"joint_{fam}"
                    else:
                        q = bad
                    key = f"arm_y_{fam}"
                elif what == 1:
                    fam, bad = junk_values(7, rng)
                    tau, key = bad, f"arm_u_{fam}"
                else:
                    fam, t = junk_stamps(r.t[k - 1], rng)
                    key = f"arm_{fam}"
                COUNTS[key] += 1
                with pytest.raises(SampleRejected):
                    dirty.update(t, q, tau)
        a = clean.update(r.t[k], r.q_measured[k], r.tau[k])
        b = dirty.update(r.t[k], r.q_measured[k], r.tau[k])
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(clean.velocity, dirty.velocity)


def test_junk_messages_into_the_external_torque_node_loop(stream):
    """The node's per-message path (runner/torque_loop.py) with junk JointStates: a junk
    value on one joint or a whole field, junk names (missing, duplicated, unknown, none) and
    junk stamps: never an exception, never a non-finite estimate, every junk message refused
    and counted (its joint's reason per joint)."""
    from fto_ros.runner.torque_loop import TorqueLoop
    from fto_ros.runner.torque_settings import build
    loop = TorqueLoop(build({"robot_description": URDF, "plant.joints": JOINTS,
                             "external_torque.window": 0.01, "collision.calibration": 0.01}))
    r, rng, junk = stream, np.random.default_rng(21), 0
    ns = lambda t: 10 ** 9 + int(round(t * 1e9))  # noqa: E731
    for k in range(r.t.size):
        if k:
            for _ in range(3):
                names, q, tau, stamp = list(JOINTS), list(r.q_measured[k]), list(r.tau[k]), \
                    ns(r.t[k])
                what = rng.integers(4)
                if what == 0:
                    fam, bad = junk_values(1, rng)
                    if fam not in ("non_finite", "absurd"):
                        continue                  # a JointState field holds floats only
                    (q if rng.random() < 0.5 else tau)[int(rng.integers(7))] = bad[0]
                    key = f"node_joint_{fam}"
                elif what == 1:
                    size = int(rng.choice([0, 6, 8, 14]))
                    if rng.random() < 0.5:
                        q = [0.0] * size
                    else:
                        tau = [0.0] * size
                    key = "node_field_wrong_length"
                elif what == 2:
                    fam = ["missing", "duplicate", "none", "unknown_only"][rng.integers(4)]
                    if fam == "missing":
                        i = int(rng.integers(7))
                        del names[i], q[i], tau[i]
                    elif fam == "duplicate":
                        names[int(rng.integers(1, 7))] = names[0]
                    elif fam == "none":
                        names, q, tau = [], [], []
                    else:
                        names = [f"other_{i}" for i in range(7)]
                    key = f"node_names_{fam}"
                else:
                    last = loop.last_t
                    fam, t = junk_stamps(r.t[k - 1], rng)
                    if not np.isfinite(t) or abs(t) > 1e9 or fam in ("stamp_back_big",
                                                                      "stamp_future"):
                        continue                  # not an int64 stamp, or a restart (not junk)
                    stamp = ns(t) if last is not None else 0
                    key = f"node_{fam}"
                COUNTS[key] += 1
                before = sum(loop.rejected.values())
                assert loop.process(stamp, names, q, tau) is None, key
                assert sum(loop.rejected.values()) == before + 1, key
                junk += 1
        res = loop.process(ns(r.t[k]), JOINTS, r.q_measured[k], r.tau[k])
        assert res is not None
        assert res.tau_ext is None or np.all(np.isfinite(res.tau_ext))
    assert junk > 50 and sum(loop.rejected.values()) == junk
    assert sum(sum(c.values()) for c in loop.joint_rejected) >= loop.rejected.get(
        "measurement_non_finite", 0)
