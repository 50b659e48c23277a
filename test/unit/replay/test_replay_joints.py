"""The replay in the per-joint mode (``joints``): one JointState in, one out per sample by
name (the per-joint source's plan, runner/sources/plan.py), the truth a JointState mapped
by name, errors per joint and over all joints; the outputs are those of the node's path
(the source's rows of one payload at a time, ``process_rows``) bit for bit, and one joint's junk leaves the others untouched."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fto_ros.bag import BagReader, BagWriter
from fto_ros.core.reasons import CODE
from fto_ros.replay.replay import replay
from fto_ros.runner import Runner
from fto_ros.bag.mcap_scan import read_raw
from fto_ros.core.cdr import JointStateDecoder
from fto_ros.runner import loop as L
from fto_ros.runner.sources import make_source
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[3]
PARAMS = [ROOT / "config" / "arm7_plant.yaml", ROOT / "config" / "arm7_luenberger.yaml"]
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
N = 1500


def _signals():
    t = np.arange(N) * 1e-3
    k = np.arange(1, 8)
    q = 0.1 * np.sin(t[:, None] * k)
    v = 0.1 * k * np.cos(t[:, None] * k)
    tau = 0.5 * np.cos(0.5 * t[:, None] * k)
    return t, q, v, tau


def _bag(path: Path) -> Path:
    """1.5 s of seven joints at 1 kHz, the names in another order from 0.5 s on; junk: joint
    a3's position NaN at sample 300, joint a5 missing at 600, a6 named twice at 900."""
    t, q, v, tau = _signals()
    with BagWriter(path) as bag:
        for i in range(N):
            t_ns = 10 ** 9 + i * 10 ** 6
            names, pos, eff = list(JOINTS), list(q[i]), list(tau[i])
            if i >= 500:
                names, pos, eff = names[::-1], pos[::-1], eff[::-1]
            if i == 300:
                pos[names.index("joint_a3")] = math.nan
            if i == 600:
                k = names.index("joint_a5")
                del names[k], pos[k], eff[k]
            if i == 900:
                k = names.index("joint_a6")
                names.append("joint_a6"), pos.append(pos[k]), eff.append(eff[k])
            bag.joint_state("/arm/joint_states", t_ns, t_ns, names, pos, (), eff)
            bag.joint_state("/arm/true_joint_states", t_ns, t_ns, JOINTS[::-1], q[i][::-1],
                            v[i][::-1], np.zeros(7))
    return path


def _node_path(bag: Path):
    """What the node does message by message: the per-joint source's rows of each raw
    payload alone, Runner.process_rows, and the plan's estimated_joint_states bytes."""
    runner = Runner(load_params_files(PARAMS, "observer_node"))
    source = make_source(runner)
    i = next(k for k, sp in enumerate(source.plan.specs) if sp.topic == "estimated_joint_states")
    dec = JointStateDecoder()
    t_log, payloads = read_raw(bag, ["/arm/joint_states"])["/arm/joint_states"]
    out = []
    for t_ns, payload in zip(t_log.tolist(), payloads):
        one = np.array([t_ns], np.int64)
        rows = source.rows("joint_states", (payload,), one, one, one * 1e-9)
        if rows.py_reasons:                      # refused before the runner, by name
            for why in rows.py_reasons.values():
                runner.reject(why)
            continue
        status, x, w, c = runner.process_rows(rows.kind, rows.t, rows.values, rows.pre)
        s = int(rows.srow[0])
        ok = status[s] == L.OUTPUT
        if ok.any():
            ns = int(rows.stamp_ns[0])
            js = dec.decode(source.plan.encode_one(i, ns // 10 ** 9, ns % 10 ** 9, x[s], w[s],
                                                   c[s], ok))
            out.append((list(js.name), js.position, js.velocity, js.effort))
    return runner, out


def test_the_replay_equals_the_node_path_and_junk_stays_in_its_joint(tmp_path):
    bag = _bag(tmp_path / "arm")
    m = replay(bag, PARAMS, tmp_path / "out", plot=False, progress=False)
    runner, want = _node_path(bag)
    got = []
    with BagReader(tmp_path / "out") as r:
        for _, _, msg in r.messages(["/observer_node/estimated_joint_states"]):
            got.append((list(msg.name), msg.position.tolist(), msg.velocity.tolist(),
                        msg.effort.tolist()))
    assert len(got) == len(want) == N
    for k, (a, b) in enumerate(zip(got, want)):
        assert a[0] == b[0], k
        for f in (1, 2, 3):
            assert np.array_equal(np.asarray(a[f]), np.asarray(b[f])), (k, f)
    # each junk sample refused for its joint only, counted with its reason
    assert m["rejected_by_reason"] == dict(runner.rejected)
    assert m["rejected_by_reason"] == {"measurement_non_finite": 1,
                                       "joint_states_joint_missing": 1,
                                       "joint_states_duplicate_joint": 1}
    assert got[300][0] == [j for j in JOINTS if j != "joint_a3"]
    assert got[600][0] == [j for j in JOINTS if j != "joint_a5"]      # in the order of joints
    assert len(got[0][0]) == 7 and len(got[0][3]) == 0    # luenberger: no unknown input
    assert m["samples_accepted"] == 7 * N - 3 and m["sample_count"] == 7 * N
    # the truth JointState, mapped by name (recorded in reverse order)
    je = m["joint_errors"]
    assert je["fields"] == ["position", "velocity"]
    assert set(je["per_joint"]) == set(JOINTS)
    for j in JOINTS:
        assert je["per_joint"][j]["matched_samples"] == N - (1 if j in ("joint_a3", "joint_a5", "joint_a6") else 0)
        assert je["per_joint"][j]["per_state"]["position"]["rms_after_settle"] < 1e-3
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["joints"] == JOINTS


@pytest.mark.parametrize("tuning", ["hosm", "luenberger"])
def test_the_arm_bag_per_joint(tmp_path, tuning):
    """The committed arm example: seven joints, every sample accepted, each joint's velocity
    error after settling within the encoder-limited figures measured (docs/replay.md)."""
    params = [ROOT / "config" / "arm7_plant.yaml", ROOT / "config" / f"arm7_{tuning}.yaml"]
    m = replay(ROOT / "bags" / "arm7_contact_link6", params, tmp_path / "o", plot=False,
               progress=False)
    assert m["samples_accepted"] == m["sample_count"] == 7 * 10001
    assert m["output_topics"]["/observer_node/estimated_joint_states"] == 10001
    je = m["joint_errors"]
    assert je["fields"] == ["position", "velocity", "effort"][:3 if tuning == "hosm" else 2]
    for j, e in je["per_joint"].items():
        # a finite-difference of the encoder (1e-5 rad at 1 kHz) would give ~0.014 rad/s rms
        assert e["per_state"]["velocity"]["rms_after_settle"] < 0.03, j
        assert e["per_state"]["position"]["rms_after_settle"] < 3e-5, j
