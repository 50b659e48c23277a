"""Issue 26 item 4: jittered sampling instants and lost messages cost the velocity estimates
(almost) nothing when the stamps are the instants; what costs is a stamp that is NOT the
instant the encoder was read.

Synthetic 7-joint streams (test/support/joint_streams.py: smooth closed-form motion with
reversals, 1e-5 rad noise, 2^-18 rad quantisation), run through the runner with the arm's
per-joint configs.  Measured (seeds 1-3, 5 s each; RMS of the velocity error from 0.5 s,
pooled over the joints; jittered / clean worst joint):

| config | clean | +-50 us instants | + 0.2 % lost | stamps +-50 us off the instants |
|---|---|---|---|---|
| arm7_joint_kalman (60 Hz) | 0.00215 | 0.00215 (1.003) | 0.00215 (1.007) | 0.0027 (1.19x; at 100 Hz 2.3x) |
| arm7_track_joint_kalman | 0.00213 | 0.00214 (1.006) | 0.00214 (1.007) | |
| arm7_hosm | 0.00930 | 0.00930 (1.001) | 0.00930 (1.002) | 0.0169 (1.8x) |
| arm7_luenberger | 0.00711 | 0.00710 (1.001) | 0.00711 (1.001) | 0.0122 (1.7x) |
| arm7_ekf | 0.00770 | 0.00769 (1.001) | 0.00770 (1.001) | 0.0153 (2.0x) |
| backward difference | 0.01439 | 0.01442 | 0.01441 | 0.0365 (2.5x) |

Every family discretises the actual step exactly (joint_kalman in closed form, hosm and
the luenberger by cached exact steps, the EKF by an exponential per step), so the instants'
jitter is harmless; a stamp off the instant by d makes every model integrate over the wrong
interval, an error of q' d (1 rad/s x 50 us = 5e-5 rad, five encoder sigmas) that no
observer can tell from motion.  That is what doubled hosm's error in the issue's run (its
stamps were not the instants): fto-simulate --urdf --stamp-noise 50 on the Panda-class arm
gives hosm 0.0161 -> 0.02-0.032 rad/s per joint, with --jitter 50 (stamps = instants)
0.0161 -> 0.0162.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import joint_streams as JS
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = ["arm7_joint_kalman", "arm7_track_joint_kalman", "arm7_hosm", "arm7_luenberger",
           "arm7_ekf"]
#: the issue's bar: jitter and losses cost under 10 %
BAR = 1.10


def rms(config: str, **stream) -> np.ndarray:
    flat = load_params_files(params_files(ROOT / "config" / f"{config}.yaml"))
    return JS.velocity_rms(Runner(flat), JS.stream(1, **stream))


@pytest.mark.parametrize("config", CONFIGS)
def test_jitter_and_losses_cost_under_ten_percent(config):
    clean = rms(config, jitter=0.0)
    for stream in (dict(jitter=50e-6), dict(jitter=50e-6, loss=0.002)):
        got = rms(config, **stream)
        ratio = got / clean
        print(config, stream, np.round(ratio, 4))
        assert np.all(ratio < BAR), (stream, ratio)


def test_a_stamp_off_the_instant_is_what_costs():
    """The same motion, stamps +-50 us off the instants (measurements at the instants):
    hosm's error more than 1.5x the clean one (measured 1.8x), joint_kalman's more than 1.1x
    (measured 1.19x at its 60 Hz, which averages the stamp error more than hosm), the
    backward difference's more than 1.5x (pooled; measured 2.5x: 1.2x on the slowest joint,
    3.6x on the fastest, the error is q' d)."""
    for config, factor in (("arm7_hosm", 1.5), ("arm7_joint_kalman", 1.1)):
        clean = rms(config, jitter=0.0)
        off = rms(config, jitter=0.0, stamp_noise=50e-6)
        assert math.sqrt(np.mean(off ** 2)) > factor * math.sqrt(np.mean(clean ** 2)), config
    bd = [JS.backward_difference_rms(JS.stream(1, jitter=0.0, stamp_noise=s)) for s in (0, 50e-6)]
    assert np.mean(bd[1] ** 2) > 1.5 ** 2 * np.mean(bd[0] ** 2)


def test_the_model_free_filter_beats_the_backward_difference():
    """On every joint of the jittered, lossy stream: at most 0.5x the backward difference's
    RMS error (measured 0.04-0.30x at the configs' 60 Hz), the track composition as the
    filter alone after the hand-over."""
    s = dict(jitter=50e-6, loss=0.002)
    bd = JS.backward_difference_rms(JS.stream(1, **s))
    for config in ("arm7_joint_kalman", "arm7_track_joint_kalman"):
        got = rms(config, **s)
        print(config, np.round(got / bd, 3))
        assert np.all(got < 0.5 * bd), (config, got / bd)
