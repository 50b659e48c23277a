"""What the plant block derives, for every observer type, as text (``fto-design``; ROS-free).

For a plant: which observer types apply and the one line that says why the others do not;
per applicable type the derived matrices and forms and the structural figures of its paper
(canonical-form conditioning, relative degree and invariant zeros, the observability form);
and for each tuning (the observer's own parameters) the observer built from the derived
parameters, with its guaranteed time and its start-up ``diagnostics()``: the design figures
(noise gain, cond(S), gains, Theorem 2's mu, ...).  Nothing runs on data.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import numpy as np

from ..core.errors import ConfigError
from .block import Plant
from .derive import DERIVES, Derivation, derive


def _shape(name: str, plant: Plant, params: Mapping[str, Any]) -> tuple[int, int] | None:
    n, m, p, q = plant.n, plant.m, plant.p, plant.q
    n1 = params.get("n_unmeasured", 0)
    return {"A": (n, n), "B": (n, m), "C": (p, n), "D": (n, q), "A1": (n1, n1), "A2": (p, n1),
            "state_map": (n, n), "chain_map": (n, n)}.get(name)


def _value(type_name: str, name: str, value: Any, plant: Plant,
           params: Mapping[str, Any]) -> list[str]:
    """Lines showing one derived parameter: matrices row by row, long text lists one item per
    line."""
    full = f"{type_name}.{name}"
    shape = _shape(name, plant, params)
    if shape and isinstance(value, list) and len(value) == shape[0] * shape[1] and shape[1] > 0:
        M = np.array(value, dtype=float).reshape(shape)
        return [f"{full} ({shape[0]}x{shape[1]}) ="] + [
            "    [" + ", ".join(f"{v:.6g}" for v in row) + "]" for row in M]
    if isinstance(value, list) and value and isinstance(value[0], str):
        if sum(len(v) for v in value) > 60:
            return [f"{full} ="] + [f"    [{i}] {v}" for i, v in enumerate(value)]
        return [f"{full} = [" + ", ".join(value) + "]"]
    if isinstance(value, list) and value and isinstance(value[0], float):
        return [f"{full} = [" + ", ".join(f"{v:.6g}" for v in value) + "]"]
    return [f"{full} = {value}"]


def classify(plant: Plant, section_of: Callable[[str], Mapping[str, Any]]
             ) -> dict[str, Derivation | ConfigError]:
    """Observer type -> its derivation, or the ConfigError that puts the plant outside its
    class (or names the tuning value the derivation needs)."""
    out: dict[str, Derivation | ConfigError] = {}
    for type_name in sorted(DERIVES):
        try:
            out[type_name] = derive(type_name, plant, section_of(type_name))
        except ConfigError as exc:
            out[type_name] = exc
    return out


def needs_tuning(exc: ConfigError, type_name: str) -> bool:
    """The derivation stopped at a missing tuning value, not at the plant's class."""
    return exc.parameter.startswith(type_name + ".")


def plant_lines(plant: Plant) -> list[str]:
    lines = [f"plant: n = {plant.n} states ({', '.join(plant.states)}), "
             f"m = {plant.m} known inputs ({', '.join(plant.inputs) or 'none'}), "
             f"{plant.q} unknown inputs ({', '.join(plant.unknown_inputs) or 'none'}), "
             f"p = {plant.p} outputs"]
    lines += [f"  {s}' = {e}" for s, e in zip(plant.states, plant.f)]
    lines += [f"  y{i} = {e}" for i, e in enumerate(plant.h)]
    return lines


def applicability_lines(results: Mapping[str, Derivation | ConfigError]) -> list[str]:
    lines = ["", "observer types:"]
    width = max(len(t) for t in results)
    for type_name, r in results.items():
        if isinstance(r, Derivation):
            lines.append(f"  {type_name:<{width}}  applies")
        elif needs_tuning(r, type_name):
            lines.append(f"  {type_name:<{width}}  applies; the derivation needs {r.parameter} "
                         f"({r.problem})")
        else:
            lines.append(f"  {type_name:<{width}}  does not apply: {r}")
    return lines


def derivation_lines(type_name: str, d: Derivation, plant: Plant, source: str = "") -> list[str]:
    lines = ["", f"== {type_name}: derived from the plant block{source} =="]
    for name, value in d.params.items():
        lines += ["  " + line for line in _value(type_name, name, value, plant, d.params)]
    lines += [f"  {k}: {v}" for k, v in d.figures.items()]
    lines += [f"  note: {n}" for n in d.notes]
    return lines


def observer_lines(label: str, observer) -> list[str]:
    """The design figures of a built observer: guaranteed time, health figure, diagnostics."""
    gt = observer.guaranteed_time
    lines = ["", f"== {label}: the observer built from the derived parameters ==",
             f"  guaranteed time: {'none (asymptotic or no computable bound)' if math.isinf(gt) else f'{gt:g} s'}",
             f"  health figure on 'convergence': {observer.HEALTH_NAME or 'none'}"]
    lines += [f"  {k}: {v}" for k, v in observer.diagnostics().items()]
    return lines


__all__ = ["applicability_lines", "classify", "derivation_lines", "needs_tuning",
           "observer_lines", "plant_lines"]
