"""track with joint_kalman as the tracker: hosm on the same integrator chain acquires
(config/arm7_track_joint_kalman.yaml), hands over on its certificate, and the tracker's
innovation test re-acquires after a jump; the two children must describe the same chain."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import joint_streams as JS
from fto_ros.core.errors import ConfigError
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[3]
CONFIG = ROOT / "config" / "arm7_track_joint_kalman.yaml"
#: what fto-tune picks on a stream of this kind (test_tune.py): with the config's one 60 Hz
#: the two fastest joints' tracker is too slow for their motion, its NIS inflated (mean 1.3
#: and 7.7 on seed 4) and it re-acquires again and again; tuned, every joint's NIS mean is
#: 0.92-1.05 and nothing re-acquires (measured, seeds 4 and 5)
TUNED = "joint_kalman.bandwidth=[34, 40, 56, 61, 72, 100, 109]"


def runner():
    flat = load_params_files([CONFIG])
    flat["joint_overrides"] = [TUNED]
    return Runner(flat)


def test_hands_over_and_tracks_like_the_filter_alone():
    s = JS.stream(4, duration=3.0)
    r = runner()
    obs = r.observers[0]
    assert obs.acquirer.TYPE == "hosm" and obs.tracker.TYPE == "joint_kalman"
    assert obs.acquirer.n_states == obs.tracker.n_states == 3
    x, ok = JS.estimates(r, s)
    assert ok.all()
    d = [o.diagnostics() for o in r.observers]
    assert [x["mode"] for x in d] == ["tracking"] * 7
    assert all(x["hand-overs"] == "1" and x["re-acquisitions"] == "0" for x in d)
    nis = [o.tracker.nis_mean for o in r.observers]
    assert all(0.8 < v < 1.2 for v in nis), nis
    flat = load_params_files([ROOT / "config" / "arm7_plant.yaml",
                              ROOT / "config" / "arm7_joint_kalman.yaml"])
    flat["joint_overrides"] = [TUNED]
    a = JS.velocity_rms(Runner(flat), s, after=1.0)
    t = JS.velocity_rms(runner(), s, after=1.0)
    assert np.all(t < 1.05 * a), (t, a)


def test_a_jump_reacquires():
    s = JS.stream(5, duration=2.0)
    s.y[1000:, 2] += 0.01                 # joint 3's encoder jumps by 10 mrad at 1 s
    r = runner()
    JS.estimates(r, s)
    d = [o.diagnostics() for o in r.observers]
    assert d[2]["re-acquisitions"] == "1" and d[2]["mode"] == "tracking"
    assert all(x["re-acquisitions"] == "0" for i, x in enumerate(d) if i != 2)


def test_orders_must_meet():
    flat = load_params_files([CONFIG])
    flat["joint_kalman.order"] = 2
    with pytest.raises(ConfigError) as err:
        Runner(flat)
    assert err.value.parameter == "track.tracker" and "states" in err.value.problem
