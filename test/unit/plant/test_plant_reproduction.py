"""Every committed DC-motor config, moved to the plant-block form (config/dc_motor_plant.yaml +
a tuning file), reproduces its explicit form (test/data/dc_motor_explicit/, the configs as they
were) on every committed bag it is replayed on: the same observer on the same samples, the
estimates (and the unknown-input estimate) within 1e-9 relative.

Both forms run through the Runner (the code path of the node and of fto-replay), fed with the
bag's input and measured_output messages in log-time order (an input before the measurement
of the same instant, as fto-replay feeds them).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fto_ros.bag import read_messages
from fto_ros.cli import report
from fto_ros.plant import DERIVES
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import plant_file_for, system_plant_file

ROOT = Path(__file__).resolve().parents[3]
EXPLICIT = ROOT / "test" / "data" / "dc_motor_explicit"
ALL_PAIRS, _ = report.plan(ROOT / "bags", ROOT / "config")
#: the pairs of the configs that existed before the plant block (dc_motor_ekf.yaml is new)
PAIRS = [p for p in ALL_PAIRS if (EXPLICIT / p.config.name).is_file()]
RTOL = 1e-9


def run(flat: dict, bag: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(estimates, unknown-input estimates or None) of every accepted sample of ``bag``."""
    r = Runner(flat)
    s = r.settings
    topics = {s["topics.measured_output"]: "y"}
    if r.observer.n_inputs:
        topics[s["topics.input"]] = "input"
    est, ui = [], []
    for topic, t_ns, msg in read_messages(bag, list(topics)):
        t = t_ns * 1e-9
        if topics[topic] == "input":
            assert r.set_input(t, list(msg.data)) is None
            continue
        out = r.process(t, list(msg.data))
        assert not isinstance(out, str), out
        est.append(out.estimate.copy())
        if out.unknown_input is not None:
            ui.append(out.unknown_input.copy())
    return np.array(est), (np.array(ui) if ui else None)


def relative_gap(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| per column over the column's largest |a|, the largest over the columns."""
    scale = np.maximum(np.max(np.abs(a), axis=0), 1e-300)
    return float(np.max(np.max(np.abs(a - b), axis=0) / scale))


def test_every_dc_motor_config_is_in_the_plant_form():
    # (the ekf and the track composition came with the plant block: no explicit form)
    assert {p.config.name for p in ALL_PAIRS} == ({p.name for p in EXPLICIT.glob("*.yaml")}
                                                 | {"dc_motor_ekf.yaml", "dc_motor_acquire_track.yaml"})
    assert all(p.plant == ROOT / "config" / "dc_motor_plant.yaml" for p in ALL_PAIRS)


@pytest.mark.parametrize("pair", PAIRS, ids=lambda p: f"{p.bag.name}-{p.config.stem}")
def test_plant_block_reproduces_the_explicit_config(pair):
    est_plant, ui_plant = run(load_params_files(pair.params), pair.bag)
    est_explicit, ui_explicit = run(load_params_files([EXPLICIT / pair.config.name]), pair.bag)
    assert est_plant.shape == est_explicit.shape and len(est_plant) > 1000
    assert relative_gap(est_explicit, est_plant) <= RTOL
    assert (ui_plant is None) == (ui_explicit is None)
    if ui_plant is not None:
        assert relative_gap(ui_explicit, ui_plant) <= RTOL


# The other examples keep their explicit configs (they are the papers' own coordinates);
# their plant files serve the EKF.  The same configs with the model taken from the plant
# file instead (every parameter the derivation gives removed) reproduce them too.
EXAMPLES = [(cfg, system_plant_file(cfg)) for cfg in sorted((ROOT / "config").glob("*.yaml"))
            if system_plant_file(cfg) and plant_file_for(cfg) is None
            and not cfg.stem.startswith("dc_motor")]


def without_model(cfg: Path) -> dict:
    """The explicit config's parameters without those the plant block derives."""
    flat = load_params_files([cfg])
    kind = flat["observer.type"]
    return {k: v for k, v in flat.items() if k[len(kind) + 1:] not in DERIVES[kind]
            or not k.startswith(kind + ".")}


def test_every_example_with_a_plant_file_is_covered():
    assert {cfg.stem for cfg, _ in EXAMPLES} == {
        "cubic_escape_global_norm", "cubic_escape_high_gain", "double_integrator_prescribed_time",
        "fld_example1_hosm", "fld_example2_hosm", "possieri_example_newton",
        "possieri_example_newton_ndim", "possieri_example_newton_notch",
        "third_order_prescribed_time", "van_der_pol_global_norm", "van_der_pol_high_gain"}


@pytest.mark.parametrize("cfg, plant", EXAMPLES, ids=lambda p: p.stem)
def test_plant_block_reproduces_the_papers_examples(cfg, plant):
    bag = ROOT / "bags" / plant.stem[:-len("_plant")]
    explicit, ui_explicit = run(load_params_files([cfg]), bag)
    derived, ui_derived = run({**load_params_files([plant]), **without_model(cfg)}, bag)
    assert explicit.shape == derived.shape and len(explicit) > 1000
    assert relative_gap(explicit, derived) <= RTOL
    if ui_explicit is not None:
        assert relative_gap(ui_explicit, ui_derived) <= RTOL
