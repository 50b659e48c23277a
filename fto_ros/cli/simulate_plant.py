"""``fto-simulate --params FILE...``: a user's plant block as a simulation model.

The params files give the plant block (``plant.*``, usually in the ``/**`` block so the
observer node reads it too) and the ``simulation.*`` parameters below, read as the node
``fto_simulate`` reads them (its own block, or ``/**``); every other parameter is left to
the observer node.  :func:`plant_spec` turns them into the same
:class:`~fto_ros.models.unknown_input.UnknownInputModelSpec` the built-in models are, so
``fto-simulate`` records the bag in the package's layout: ``/<system>/input``,
``measured_output``, ``true_state``, ``true_unknown_input`` (with unknown inputs),
``joint_states`` (with ``simulation.joint_names``) and ``/clock``.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import sympy

from ..core.errors import ConfigError
from ..core.expressions import compile_exprs, parse
from ..models.unknown_input import UnknownInputModelSpec
from ..core.params import Param, resolve
from ..plant import resolve_plant
from ..plant.block import compiled
from ..runner.params_file import load_params_files

#: the node name whose params block fto-simulate reads
NODE_NAME = "fto_simulate"
PREFIX = "simulation."

SIM_PARAMS: tuple[Param, ...] = (
    Param("system", "string", None, "system name: the bag's topics are /<system>/..."),
    Param("duration", "double", 10.0, "simulated time (s)", min=1e-9),
    Param("rate", "double", 1000.0, "rate of the input, the measurements (unless sparse), the "
          "ground truth and /clock (Hz)", min=1e-9),
    Param("initial_state", "double_array", None, "x(0), one value per plant state"),
    Param("input", "string_array", [], "u(t): one expression in t (and the plant's constants) "
          "per known input, e.g. '0.5*sin(2*t)'"),
    Param("input_hold", "string", "zoh", "'zoh': u sampled at the rate and held (a DAC; the "
          "bag's input is what the plant got), 'smooth': the plant sees u(t) itself",
          choices=("zoh", "smooth")),
    Param("unknown_input", "string_array", [], "d(t): one expression in t per unknown input "
          "(empty: zero), recorded on /<system>/true_unknown_input"),
    Param("noise", "double_array", [], "standard deviation of the Gaussian measurement noise: "
          "one value, or one per output (empty: none)", min=0.0),
    Param("seed", "int", 0, "seed of the noise (and of sparse sampling)", min=0),
    Param("joint_names", "string_array", [], "one joint per output: the measurement is also "
          "published as sensor_msgs/JointState positions on /<system>/joint_states"),
)


def load(paths: Sequence[str | Path], overrides: Mapping[str, Any] | None = None
         ) -> tuple[Any, dict[str, Any]]:
    """(plant, typed simulation settings) from the params files, or ConfigError."""
    flat = load_params_files(paths, NODE_NAME, overrides)
    values = {k[len(PREFIX):]: v for k, v in flat.items() if k.startswith(PREFIX)}
    sim = resolve(SIM_PARAMS, values, prefix=PREFIX)
    if not any(k.startswith("plant.") for k in flat):
        raise ConfigError("plant.states", "no plant block in the params files (fto-simulate "
                          f"reads the blocks '/**' and '{NODE_NAME}')")
    return resolve_plant(flat), sim


def _time_functions(texts: list[str], count: int, plant, name: str, what: str):
    """t -> array of ``count`` values from expressions in t and the plant's constants."""
    P = PREFIX + name
    if texts and len(texts) != count:
        raise ConfigError(P, f"expected {count} expression(s), one per {what}, got {len(texts)}")
    if count and not texts:
        if name == "input":
            raise ConfigError(P, f"give u(t) for every known input ({', '.join(plant.inputs)})")
        return (lambda t: np.zeros(count)), "zero"
    t = sympy.Symbol("t", real=True)
    consts = [sympy.Symbol(k, real=True) for k in plant.constants]
    subs = {c: sympy.Float(plant.constants[c.name]) for c in consts}
    exprs = [parse(s, [t] + consts, f"{P}[{i}]").xreplace(subs) for i, s in enumerate(texts)]
    fn = compile_exprs(exprs, [t])
    for probe in (0.0, 0.5, 1.0):
        try:
            vals = fn(probe)
        except (ValueError, OverflowError, ZeroDivisionError) as exc:
            raise ConfigError(P, f"not defined at t = {probe}: {exc}") from None
        if not all(math.isfinite(v) for v in vals):
            raise ConfigError(P, f"not finite at t = {probe}")
    return (lambda s: np.array(fn(float(s)), dtype=float)), ", ".join(
        f"{n}(t) = {e}" for n, e in zip(plant.inputs if name == "input" else plant.unknown_inputs,
                                         texts))


def plant_spec(plant, sim: Mapping[str, Any], source: str) -> UnknownInputModelSpec:
    """The plant and the simulation settings as a model spec (see the module doc)."""
    if not sim["system"]:
        raise ConfigError(PREFIX + "system", "missing: the topics' namespace, e.g. pendulum")
    x0 = sim["initial_state"]
    if x0 is None or len(x0) != plant.n:
        raise ConfigError(PREFIX + "initial_state", f"expected {plant.n} values "
                          f"({', '.join(plant.states)}), got {0 if x0 is None else len(x0)}")
    for i, e in enumerate(plant.h):
        if e.free_symbols & set(plant.u):
            raise ConfigError(f"plant.h[{i}]", "fto-simulate records outputs of the state only "
                              "(no input feedthrough)")
    noise = sim["noise"]
    if noise and len(noise) not in (1, plant.p):
        raise ConfigError(PREFIX + "noise", f"expected 1 or {plant.p} values, got {len(noise)}")
    joints = sim["joint_names"]
    if joints and len(joints) != plant.p:
        raise ConfigError(PREFIX + "joint_names", f"expected one joint per output ({plant.p}), "
                          f"got {len(joints)}")
    u_of_t, u_text = _time_functions(sim["input"], plant.m, plant, "input", "known input")
    d_of_t, d_text = _time_functions(sim["unknown_input"], plant.q, plant, "unknown_input",
                                     "unknown input")
    f_fn, h_fn = compiled(plant)
    smooth = sim["input_hold"] == "smooth"
    empty, no_input = (), np.zeros(plant.m)

    def make_rhs(_params):
        def rhs(t, x, u):
            return np.array(f_fn(x, u_of_t(t) if smooth else u, d_of_t(t) if plant.q else empty))
        return rhs

    return UnknownInputModelSpec(
        name=sim["system"], description=f"plant block of {source}",
        state_names=tuple(plant.states), input_names=tuple(plant.inputs),
        output_names=tuple(f"y{i}" for i in range(plant.p)),
        default_params=dict(plant.constants), make_rhs=make_rhs,
        output=lambda x: np.array(h_fn(x, no_input), dtype=float),
        default_x0=tuple(x0), default_input=u_of_t,
        input_description=u_text + (" (the plant sees u(t) itself; the bag has its samples)"
                                    if smooth else ""),
        joint_names=tuple(joints),
        unknown_input=d_of_t if plant.q else None,
        unknown_input_names=tuple(plant.unknown_inputs), unknown_input_description=d_text,
        system_name=sim["system"])
