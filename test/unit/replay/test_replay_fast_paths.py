"""The replay's fast paths: its raw MCAP reader against BagReader, the BagReader fallback
giving the same replay, and every sample rejected (the codec against rosbags: test/unit/core/test_cdr.py)."""
from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from fto_ros.bag import BagReader, BagWriter
from fto_ros.bag.mcap_scan import NotFast, read_raw
from fto_ros.core.cdr import FloatDecoder
from fto_ros.replay import ReplayError, replay
from replay_bags import LUENBERGER, NS, read_topic
from replay_bags import sim, bad_bag  # noqa: F401 (fixtures)

streams_module = importlib.import_module("fto_ros.replay.streams")


# ------------------------------------------------------------------ fast paths
def test_fast_reader_matches_bagreader(bad_bag):
    topics = [f"{NS}/measured_output", f"{NS}/input", f"{NS}/true_state"]
    fast = read_raw(Path(bad_bag), topics)
    with BagReader(bad_bag) as b:
        for topic in topics:
            ref = [(t, msg) for _, t, msg in b.messages([topic])]
            t_fast, payloads = fast[topic]
            assert t_fast.tolist() == [t for t, _ in ref]
            dec = FloatDecoder()                     # mixed lengths: message by message
            vals = [dec.decode(p) for p in payloads]
            assert len(vals) == len(ref)
            for v, (_, msg) in zip(vals, ref):
                np.testing.assert_array_equal(np.asarray(v, dtype=float), msg.data)


def test_bagreader_fallback_gives_the_same_replay(bad_bag, tmp_path, monkeypatch):
    """Bags the fast path does not take (SQLite3, file compression ...) go through BagReader."""
    fast = replay(bad_bag, LUENBERGER, tmp_path / "fast", progress=False, plot=False)

    def not_fast(*args):
        raise NotFast("forced by the test")

    monkeypatch.setattr(streams_module, "read_raw", not_fast)
    slow = replay(bad_bag, LUENBERGER, tmp_path / "slow", progress=False, plot=False)
    assert slow["reader"] == "rosbags BagReader (forced by the test)"
    assert fast["reader"] == "MCAP fast path"
    for key in ("samples_accepted", "rejected_by_reason", "errors", "convergence_time_s",
                "output_topics"):
        assert slow[key] == fast[key], key
    for topic in ("/observer_node/state_estimate", f"{NS}/true_state"):
        a = [(t, list(m.data)) for t, m in read_topic(tmp_path / "fast", topic)]
        b = [(t, list(m.data)) for t, m in read_topic(tmp_path / "slow", topic)]
        assert a == b, topic


def test_all_samples_rejected(sim, tmp_path):
    path = tmp_path / "allbad"
    with BagWriter(path) as bag:
        for k in range(50):
            bag.float_array(f"{NS}/input", k * 10**6, [1.0])
            bag.float_array(f"{NS}/measured_output", k * 10**6, [1.0, 2.0])
            bag.float_array(f"{NS}/true_state", k * 10**6, [0.0, 0.0, 0.0])
    # a replay that accepts nothing fails, after writing what it has (to look at)
    with pytest.raises(ReplayError, match=r"no sample accepted of 50 \(rejected: "
                                          r"measurement_wrong_length: 50\)"):
        replay(path, LUENBERGER, tmp_path / "out", progress=False)
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["samples_accepted"] == 0
    assert m["rejected_by_reason"] == {"measurement_wrong_length": 50}
    assert m["errors"] is None and "no accepted samples" in m["errors_note"]
    assert m["final_status"]["level"] == "WARN"
    assert (tmp_path / "out" / "replay.png").stat().st_size > 0
