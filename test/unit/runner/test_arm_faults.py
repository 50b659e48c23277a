"""Junk into an arm's external-torque families on the runner's rules (external_torque,
momentum_observer): junk values (NaN, inf, huge, wrong lengths, wrong types) in the
positions (y) or the efforts (u), junk stamps (repeated, going back, negative, too close,
non-finite, far ahead), and junk JointStates on the node's message path
(runner/messages.py's joint_state_sample with the family's intake, runner/arm_intake.py):
a listed joint missing, a name twice, a position or effort array not as long as the
names, no names, only unknown names, one joint NaN / inf / huge. Every junk sample is
refused with its reason and counted (or, for a stamp far off, held and dropped by the
runner's timeline), nothing non-finite is ever published, nothing raises, and the
estimator goes on exactly as a twin that never saw the junk (every output equal, bit for
bit). The cases of the deleted torque node's fault tests, on the new path. ROS-free."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from arm_families import ARM7, ARM7_JOINTS, runner
from faultkit import COUNTS, check_result, junk_stamps, junk_values
from fto_ros.arm import load_model
from fto_ros.models.arm import ArmSettings, Contact, simulate_arm
from fto_ros.runner.runner import HELD
from fto_ros.runner.messages import joint_state_sample

FAMILIES = ("external_torque", "momentum_observer")
#: short windows and calibration, so estimates, levels and a contact come within the stream
SHORT = {"external_torque": dict(external_torque__window=0.012),
         "momentum_observer": dict(momentum_observer__gain=100.0)}


@pytest.fixture(scope="module")
def stream():
    model = load_model(ARM7_JOINTS, urdf=ARM7)
    return simulate_arm(model, ArmSettings(duration=0.2, seed=9, jitter=5e-5,
                                           contacts=[Contact("link_4", 0.12, 0.05, (0, 150, 0))]))


def _make(family):
    return runner(family, ARM7, joints=ARM7_JOINTS, collision__calibration=0.03,
                  **SHORT[family])


def _same(a, b):
    """Two runner results alike to the last bit (a reason, HELD or an Output)."""
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    for x, y in ((a.estimate, b.estimate), (a.unknown_input, b.unknown_input),
                 (a.convergence, b.convergence)):
        np.testing.assert_array_equal(x, y)


def _clean(r, t, y, u):
    assert r.set_input(t, u) is None
    return r.process(t, y)


@pytest.mark.parametrize("family", FAMILIES)
def test_junk_samples_are_refused_counted_and_leave_the_estimator_as_its_twin(stream, family):
    r = stream
    twin, dirty = _make(family), _make(family)
    rng = np.random.default_rng(5)
    junk = held = 0
    prev = None
    for k in range(r.t.size):
        t, y, u = float(r.t[k]), r.q_measured[k], r.tau[k]
        if k:
            for _ in range(2):
                before = sum(dirty.rejected.values())
                what = rng.integers(3)
                if what == 0:                              # y: one joint, or the whole vector
                    fam, bad = junk_values(7, rng)
                    if fam in ("non_finite", "absurd") and rng.random() < 0.5:
                        bad = list(y)
                        bad[int(rng.integers(7))] = [np.nan, np.inf, -1e300][rng.integers(3)]
                        fam = "one_joint"
                    key, res = f"arm_y_{fam}", dirty.process(t, bad)
                elif what == 1:                            # u: the efforts and passive joints
                    fam, bad = junk_values(7, rng)
                    key, res = f"arm_u_{fam}", dirty.set_input(t, bad)
                else:
                    fam, ts = junk_stamps(float(r.t[k - 1]), rng)
                    key, res = f"arm_{fam}", dirty.process(ts, y)
                COUNTS[key] += 1
                if res == HELD:                            # held at a time jump
                    held += 1
                    prev = (key, res)
                    continue
                assert isinstance(res, str) and res, (key, res)
                assert sum(dirty.rejected.values()) == before + 1, (key, res, prev)
                junk += 1
                prev = (key, res)
        a, b = _clean(twin, t, y, u), _clean(dirty, t, y, u)
        check_result(b)
        _same(a, b)
    obs = dirty.observer
    assert junk > 150 and held > 0
    assert obs.calibrated and np.isfinite(obs.unknown_input).all()
    # the stream reached the contact: a level crossed, on both alike
    assert int(obs.diagnostics()["contact onsets"]) >= 1
    assert dirty.resets == twin.resets


def _msg(sec_ns: int, names, position, effort):
    stamp = SimpleNamespace(sec=sec_ns // 10 ** 9, nanosec=sec_ns % 10 ** 9)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), name=list(names),
                           position=list(position), effort=list(effort))


def _node_path(r, msg):
    """What the node does with one JointState (nodes/observer_core.py _on_joint_states):
    the sample or the reason, counted; the runner's result."""
    sample = joint_state_sample(msg, r.settings, None, r.intake)
    if isinstance(sample, str):
        r.reject(sample)
        return sample
    t, y, u = sample
    reason = r.set_input(t, u)
    return reason if reason is not None else r.process(t, y)


@pytest.mark.parametrize("family", FAMILIES)
def test_junk_joint_states_on_the_node_path(stream, family):
    r = stream
    twin, dirty = _make(family), _make(family)
    rng = np.random.default_rng(21)
    ns = lambda t: 10 ** 9 + int(round(t * 1e9))          # noqa: E731
    reasons, junk = set(), 0
    for k in range(r.t.size):
        clean = _msg(ns(r.t[k]), ARM7_JOINTS, r.q_measured[k], r.tau[k])
        if k:
            for _ in range(3):
                names, q, tau = list(ARM7_JOINTS), list(r.q_measured[k]), list(r.tau[k])
                stamp = ns(r.t[k])
                what = rng.integers(5)
                if what == 0:
                    bad = [np.nan, np.inf, -np.inf, 1e300, -1e300][rng.integers(5)]
                    (q if rng.random() < 0.5 else tau)[int(rng.integers(7))] = bad
                    key = "node_joint_value"
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
                elif what == 3:                        # back, repeated, too close, zero step
                    step = [-2e-4, -1e-3, 0.0, 1e-8][rng.integers(4)]
                    stamp = ns(r.t[k - 1] + step)
                    key = "node_stamp_back_or_zero_step"
                else:                                  # the previous message again
                    stamp, q, tau = ns(r.t[k - 1]), list(r.q_measured[k - 1]), list(r.tau[k - 1])
                    key = "node_repeated_message"
                COUNTS[key] += 1
                before = sum(dirty.rejected.values())
                res = _node_path(dirty, _msg(stamp, names, q, tau))
                assert isinstance(res, str) and res != HELD, (key, res)
                assert sum(dirty.rejected.values()) == before + 1, key
                reasons.add(res)
                junk += 1
        a, b = _node_path(twin, clean), _node_path(dirty, clean)
        check_result(b)
        _same(a, b)
    assert junk > 300
    # each kind refused with its own reason
    assert {"joint_states_joint_missing", "joint_states_duplicate_name",
            "joint_states_position_missing", "joint_states_effort_missing"} <= reasons, reasons
    assert len(reasons) >= 6, reasons
    assert dirty.observer.calibrated and np.isfinite(dirty.observer.unknown_input).all()


@pytest.mark.parametrize("family", FAMILIES)
def test_a_passive_joint_missing_or_junk_is_no_sample_error(stream, family):
    """The gripper's fingers (passive joints) may be absent from a message: the last known
    position is kept and the sample is taken; a NaN finger position is refused like any
    junk input."""
    from arm_families import PANDA, PANDA_JOINTS
    run = runner(family, PANDA, joints=PANDA_JOINTS, **SHORT[family])
    fingers = run.observer.passive_joints
    assert fingers
    q = [0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8]
    out = _node_path(run, _msg(10 ** 9, PANDA_JOINTS, q, [0.0] * 7))
    assert not isinstance(out, str)
    names = PANDA_JOINTS + fingers
    bad = _node_path(run, _msg(10 ** 9 + 10 ** 6, names, q + [np.nan] * len(fingers),
                               [0.0] * len(names)))
    assert bad == "input_non_finite" or (isinstance(bad, str) and "non_finite" in bad), bad
    ok = _node_path(run, _msg(10 ** 9 + 2 * 10 ** 6, names, q + [0.02] * len(fingers),
                              [0.0] * len(names)))
    assert not isinstance(ok, str)
    np.testing.assert_array_equal(run.intake.last, [0.02] * len(fingers))
