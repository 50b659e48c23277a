"""The plant block (fto_ros/plant/): parsing, each observer's derivation, the refusals, the
conflicts with explicit parameters, re-derivation on a runtime change, the observability form
through a linear map, known inputs in global_norm/high_gain, and the plant-file convention."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import sympy

from fto_ros.core.errors import ConfigError
from fto_ros.models.simulate import simulate
from fto_ros.observers import REGISTRY
from fto_ros.plant import DERIVES, derive, expand, resolve_plant
from fto_ros.plant.block import compiled
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files, plant_file_for
from registry_tables import expected

ROOT = Path(__file__).resolve().parents[3]
DC = load_params_files([ROOT / "config" / "dc_motor_plant.yaml"])
DC_PLANT = {k: v for k, v in DC.items() if k.startswith("plant.")}
PENDULUM = {"plant.states": ["theta", "omega"], "plant.inputs": ["tau"],
            "plant.constants": ["g=9.81", "l=0.5", "c=0.4", "J=0.2"],
            "plant.f": ["omega", "-g/l*sin(theta) - c*omega + tau/J"], "plant.h": ["theta"]}


def derived(plant_flat, type_name, **section):
    return derive(type_name, resolve_plant(plant_flat), section)


def test_dc_motor_single_delay_is_the_papers_eq_66_67():
    d = derived(DC_PLANT, "single_delay", k=100.0)
    p = d.params
    assert p["A1"] == [-1.0, 15.0, -36.4, -200.0] and p["A2"] == [1.0, 0.0]      # eq. (67)
    # F2 is the plant's own term G of q' = q_dot (none): the observer adds k y itself
    assert p["F1"] == ["-35.0*sin(y0)", "40.0*u0"] and p["F2"] == ["0"]
    assert (p["lipschitz_K1"], p["lipschitz_K2"]) == (35.0, 0.0)     # K1 = a1; the bounds add k
    assert p["state_map"] == [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert any("tau_L = 0" in n for n in d.notes)
    assert derived(DC_PLANT, "single_delay", k=150.0).params["F2"] == ["0"]     # k-free


def test_dc_motor_canonical_form():
    p = derived(DC_PLANT, "prescribed_time").params
    # s^3 + (a2 + a4) s^2 + (a2 a4 + a3 b1) s, b0 b1 = 600; T maps sin q terms too
    assert p["a"] == [201.0, 746.0, 0.0] and p["b"] == [600.0] and p["relative_degree"] == 3
    assert p["F"] == ["0", "-35.0*sin(y0)", "-7000.0*sin(y0)"]
    S = np.array(p["state_map"]).reshape(3, 3)             # x = S x_c
    assert np.allclose(np.linalg.inv(S)[1], [201.0, 1.0, 0.0])    # x_c2 = q_dot + a y


def test_dc_motor_linear_forms_and_models_as_text():
    h = derived(DC_PLANT, "hosm").params
    assert h["A"] == [0.0, 1.0, 0.0, 0.0, -1.0, 15.0, 0.0, -36.4, -200.0]
    assert h["B"] == [0.0, 0.0, 40.0] and h["C"] == [1.0, 0.0, 0.0]
    assert h["D"] == [0.0, -15.0, 0.0] and h["unknown_input_names"] == ["tau_L"]
    assert h["F"] == ["0", "-35.0*sin(y0)", "0"]
    n = derived(DC_PLANT, "newton_inversion").params
    assert n["f"][1] == "-a1*sin(q) - a2*q_dot + b1*current"         # tau_L = 0, constants kept
    assert n["constants"] == DC_PLANT["plant.constants"]


#: per registered observer family, the plant its derivation is checked on (None: a
#: composition of other families, which derives nothing itself); a family registered
#: without an entry here fails test_each_derivation_gives_exactly_its_declared_parameters
DERIVATION_PLANT = {"single_delay": DC_PLANT, "prescribed_time": DC_PLANT, "luenberger": DC_PLANT,
                    "hosm": DC_PLANT, "newton_inversion": DC_PLANT, "ekf": DC_PLANT,
                    "global_norm": PENDULUM, "high_gain": PENDULUM, "joint_kalman": PENDULUM,
                    "track": None, "external_torque": None, "momentum_observer": None,
                    "arm_kalman": None}


@pytest.mark.parametrize("type_name", sorted(REGISTRY))
def test_each_derivation_gives_exactly_its_declared_parameters(type_name):
    plant = expected(DERIVATION_PLANT, type_name, "DERIVATION_PLANT (test_plant.py)",
                     "the plant its derivation is checked on, or None for a composition")
    if plant is None:        # a composition (its children derive) or an arm (its URDF is its plant)
        assert type_name not in DERIVES
        return
    d = derived(plant, type_name, k=100.0)
    assert set(d.params) == set(DERIVES[type_name])
    assert set(d.params) <= {p.name for p in REGISTRY[type_name].PARAMS}


def test_the_derivation_table_names_registered_families_only():
    assert set(DERIVATION_PLANT) <= set(REGISTRY), set(DERIVATION_PLANT) - set(REGISTRY)
    assert set(DERIVES) <= set(REGISTRY), set(DERIVES) - set(REGISTRY)


def flat_with(type_name, plant=PENDULUM, **params):
    flat = dict(plant, **{"observer.type": type_name})
    flat.update({k.replace("__", "."): v for k, v in params.items()})
    return flat


@pytest.mark.parametrize("edit, type_name, parameter, says", [
    ({"plant.f": ["omega", "-c*omega*sin(theta) + tau"]}, "luenberger", "plant.f[1]",
     "luenberger needs a linear plant (up to known terms in the measured outputs and inputs): "
     "plant.f[1] has -0.4*omega*sin(theta) (omega is not measured)"),
    ({"plant.f": ["omega + sin(omega)", "tau"]}, "prescribed_time", "plant.f[0]",
     "sin(omega) (omega is not measured)"),
    ({"plant.f": ["omega", "-g*sin(theta) + zeta"]}, "ekf", "plant.f[1]",
     "uses unknown name(s) zeta"),
    ({"plant.f": ["omega"]}, "ekf", "plant.f", "expected 2 expression(s)"),
    ({"plant.f": ["omega", "theta - c*omega"], "plant.h": ["omega**2 - omega**2 + 1"]}, "ekf",
     "plant.h", "not observable from h"),
    ({"plant.f": ["omega", "-c*omega + tau/J"], "plant.h": ["omega"], "plant.unknown_inputs": ["d"]},
     "ekf", "plant.h", "a mode at 0 that the output never sees (theta does not show"),
    ({"plant.h": ["omega"], "plant.f": ["omega", "-c*omega + tau/J"]}, "luenberger", "plant.h",
     "theta does not show in the output"),
    ({"plant.h": ["sin(theta)"]}, "luenberger", "plant.h[0]", "outputs linear in the states"),
    ({"plant.h": ["theta + tau"]}, "luenberger", "plant.h[0]", "without input feedthrough"),
    ({}, "hosm", "plant.unknown_inputs", "the plant has none"),
    ({"plant.h": ["theta", "omega"]}, "single_delay", "plant.h", "every state is measured"),
    ({"plant.h": ["theta + omega"]}, "single_delay", "plant.h[0]", "outputs that are states"),
    ({"plant.f": ["omega + theta**2", "tau"]}, "global_norm", "plant.f[0]",
     "observability form up to a constant linear map: plant.f[0] has theta**2"),
    ({"plant.h": ["theta", "omega"]}, "high_gain", "plant.h", "one output"),
    ({"plant.constants": ["g=9.81", "l=g*x"]}, "ekf", "plant.constants[1]", "unknown name"),
    ({"plant.states": ["theta", "sin"]}, "ekf", "plant.states", "reserved"),
    ({"plant.stats": ["a"]}, "ekf", "plant.stats", "unknown parameter"),
])
def test_a_plant_outside_a_class_is_refused_in_one_line(edit, type_name, parameter, says):
    flat = flat_with(type_name, ekf__process_noise=[1.0, 1.0], ekf__measurement_noise=[1.0],
                     single_delay__k=10.0, single_delay__tau=0.5)
    flat.update(edit)
    with pytest.raises(ConfigError) as e:
        Runner(flat)
    assert e.value.parameter == parameter, str(e.value)
    assert says in str(e.value) and "\n" not in str(e.value)


def test_missing_tuning_and_both_forms_are_refused_naming_them():
    with pytest.raises(ConfigError) as e:
        Runner(flat_with("single_delay", single_delay__tau=0.5))
    assert e.value.parameter == "single_delay.k" and "required" in str(e.value)
    with pytest.raises(ConfigError) as e:
        Runner(flat_with("single_delay", single_delay__k=10.0, single_delay__tau=0.5,
                         single_delay__A1=[-0.4]))
    assert e.value.parameter == "single_delay.A1" and "plant.f" in str(e.value)
    with pytest.raises(ConfigError) as e:                 # a tuning value out of range
        Runner(flat_with("single_delay", single_delay__k=10.0, single_delay__tau=-1.0))
    assert e.value.parameter == "single_delay.tau"


def test_defaults_the_node_declares_are_no_conflict():
    """The node fills every declared parameter with its default ([] for an unset array):
    those are replaced by the derived values, not refused."""
    flat = flat_with("single_delay", single_delay__k=10.0, single_delay__tau=0.5,
                     single_delay__F1=[], single_delay__n_outputs=1, single_delay__state_map=[])
    flat.update({"plant.unknown_inputs": []})
    assert Runner(flat).observer.state_names == ["theta", "omega"]


def test_a_runtime_change_of_k_keeps_f2_consistent():
    flat = flat_with("single_delay", single_delay__k=10.0, single_delay__tau=0.5)
    r = Runner(flat)
    # the paper's F2 = G + k y, G = 0 for theta' = omega: formed from k by the observer
    assert r.observer.k == 10.0 and r.observer.F.exprs[-1].equals(10.0 * r.observer.F.y_syms[0])
    changed = dict(flat, **{"single_delay.k": 20.0})
    r.reconfigure(changed)
    assert r.observer.k == 20.0 and r.observer.F.exprs[-1].equals(20.0 * r.observer.F.y_syms[0])
    assert "single_delay.F2" not in changed and "single_delay.F2" not in flat   # never stored
    r.reconfigure(dict(changed, **{"plant.constants": ["g=9.81", "l=1.0", "c=0.4", "J=0.2"]}))
    assert "9.81*sin(y0)" in str(r.observer.F.exprs[0])


def test_pendulum_single_delay_is_exact_after_tau():
    flat = flat_with("single_delay", single_delay__k=20.0, single_delay__tau=0.3)
    fn, _ = compiled(resolve_plant(flat))
    t = np.arange(1001) * 1e-3
    sim = simulate(lambda t_, x, u: np.array(fn(x, u, [])), [1.0, 0.5], t,
                   lambda s: [0.2 * math.sin(3.0 * s)])
    r = Runner(flat)
    err = []
    for k in range(len(t)):
        r.set_input(t[k], sim.u[k])
        out = r.process(t[k], sim.x[k, :1])
        err.append(np.abs(out.estimate - sim.x[k]))
    err = np.array(err)
    # exact after tau = 0.3 s up to the first-order hold of y between 1 kHz samples
    assert err[0, 1] > 0.4 and np.max(err[400:]) < 1e-4, np.max(err[400:])


def chain_flat(type_name, **params):
    """A plant in observability form only through z = T x: y = 2 p, (p, v) -> (2p, 2v)."""
    plant = {"plant.states": ["p", "v"], "plant.inputs": ["F"],
             "plant.f": ["v", "-p - p**3 - v + F"], "plant.h": ["2*p"]}
    return flat_with(type_name, plant, **params)


@pytest.mark.parametrize("type_name", ["global_norm", "high_gain"])
def test_observability_form_through_a_linear_map(type_name):
    flat = chain_flat(type_name, **{"observer.initial_estimate": [0.1, -0.5]},
                      **({"global_norm.conditions": "warn", "global_norm.gamma_hat": "10 + 10*w"}
                         if type_name == "global_norm" else {"high_gain.L": 20.0}))
    flat_out = expand(flat)
    y, x1, u0 = sympy.symbols("y x1 u0")
    # z = (2p, 2v): z1' = 2 (-p - p^3 - v + F) with p = y/2, v = x1/2
    assert sympy.simplify(sympy.sympify(flat_out[f"{type_name}.f"])
                          - (2 * u0 - x1 - y - y ** 3 / 4)) == 0
    r = Runner(flat)
    obs = r.observer
    assert obs.state_names == ["p", "v"] and obs.n_inputs == 1
    fn, hn = compiled(resolve_plant(flat))
    t = np.arange(3001) * 1e-3
    sim = simulate(lambda t_, x, u: np.array(fn(x, u, [])), [0.5, 0.0], t,
                   lambda s: [math.sin(2.0 * s)])
    est = []
    for k in range(len(t)):
        r.set_input(t[k], sim.u[k])
        out = r.process(t[k], [2.0 * sim.x[k, 0]])
        est.append(out.estimate.copy())
    est = np.array(est)
    assert np.allclose(est[0], [0.1, -0.5])        # initial estimate in plant coordinates
    assert np.max(np.abs(est[1500:] - sim.x[1500:])) < 1e-4


def test_global_norm_known_input_plumbing_leaves_an_unused_input_without_effect():
    """n_inputs = 1 with an f that does not use u0 gives bit-identical estimates to the
    input-free observer: the input changes nothing but what f reads."""
    base = {"observer.type": "global_norm", "global_norm.f": "(1 - y**2)*x1 - y",
            "global_norm.gamma_1": "y**2", "global_norm.gamma_hat": "4 + 4*w",
            "global_norm.c": [80.0, 6.0]}
    a = Runner(base).observer
    b = Runner(dict(base, **{"global_norm.n_inputs": 1})).observer
    a.reset(0.0, [1.0, -1.0])
    b.reset(0.0, [1.0, -1.0])
    for k in range(500):
        y = np.array([2.0 * math.cos(1e-3 * k)])
        a.update(1e-3 * k, y, np.zeros(0))
        b.update(1e-3 * k, y, np.array([math.sin(k)]))
        assert a.estimate.tolist() == b.estimate.tolist()


def test_plant_file_convention(tmp_path):
    cfg = tmp_path / "config"
    cfg.mkdir()
    (cfg / "sys_a_plant.yaml").write_text("/**:\n  ros__parameters:\n    plant: {states: [x]}\n")
    tuning = "observer_node:\n  ros__parameters:\n    observer: {type: luenberger}\n"
    (cfg / "sys_a_luenberger.yaml").write_text(tuning)
    (cfg / "sys_a_explicit.yaml").write_text(tuning + "    luenberger: {A: [1.0]}\n")
    (cfg / "sys_b_luenberger.yaml").write_text(tuning)
    assert plant_file_for(cfg / "sys_a_luenberger.yaml") == cfg / "sys_a_plant.yaml"
    assert plant_file_for(cfg / "sys_a_explicit.yaml") is None      # has its own model
    (cfg / "sys_a_own.yaml").write_text(tuning + "    plant: {states: [z]}\n")
    assert plant_file_for(cfg / "sys_a_own.yaml") is None            # a plant block of its own
    (cfg / "sys_a_amend.yaml").write_text(tuning + "    plant: {f: [-x]}\n")
    assert plant_file_for(cfg / "sys_a_amend.yaml") == cfg / "sys_a_plant.yaml"   # amends it
    assert plant_file_for(cfg / "sys_b_luenberger.yaml") is None    # no plant file
    assert plant_file_for(cfg / "sys_a_plant.yaml") is None          # not a tuning file
    assert params_files(cfg / "sys_a_luenberger.yaml") == [cfg / "sys_a_plant.yaml",
                                                           cfg / "sys_a_luenberger.yaml"]


#: per registered observer family, the tuning that builds it from the pendulum's plant block
#: (``section.name``: value; a composition's children's sections too); a family registered
#: without an entry here fails the test below, naming it
TUNING = {
    "single_delay": {"single_delay.k": 10.0, "single_delay.tau": 0.5},
    "prescribed_time": {"prescribed_time.T": 1.0, "prescribed_time.l": [2.0, 1.0]},
    "luenberger": {"luenberger.poles": [-5.0, -6.0]},
    "newton_inversion": {},
    "global_norm": {"global_norm.conditions": "warn"},
    "high_gain": {},
    "ekf": {"ekf.process_noise": [1.0, 1.0], "ekf.measurement_noise": [1.0]},
    "hosm": {"hosm.poles": [-5.0, -6.0], "hosm.M": [10.0]},
    "track": {"track.acquirer": "single_delay", "track.tracker": "ekf",
              "single_delay.k": 10.0, "single_delay.tau": 0.5,
              "ekf.process_noise": [1.0, 1.0], "ekf.measurement_noise": [1.0]},
    "joint_kalman": {"joint_kalman.order": 2, "joint_kalman.bandwidth": [5.0],
                     "joint_kalman.encoder_noise": [1e-3], "joint_kalman.sample_period": 0.01},
    # an arm family's plant is its URDF, never the plant block (observers/arm_base.py)
    "external_torque": None, "momentum_observer": None, "arm_kalman": None,
}


@pytest.mark.parametrize("type_name", sorted(REGISTRY))
def test_every_observer_type_builds_from_the_plant_block_with_only_its_tuning(type_name):
    tuning = expected(TUNING, type_name, "TUNING (test_plant.py)",
                      "the tuning that builds it from the plant block")
    if tuning is None:
        assert getattr(REGISTRY[type_name], "ARM", False), type_name
        return
    plant = dict(PENDULUM, **({"plant.unknown_inputs": ["d"],
                               "plant.f": ["omega", "-g/l*sin(theta) - c*omega + (tau + d)/J"]}
                              if type_name == "hosm" else {}))
    obs = Runner(dict(flat_with(type_name, plant), **tuning)).observer
    assert obs.TYPE == type_name and obs.state_names == ["theta", "omega"], type_name


def test_the_tuning_table_names_registered_families_only():
    assert set(TUNING) <= set(REGISTRY), set(TUNING) - set(REGISTRY)
