"""The plant written once (``plant.*`` parameters) and what each observer derives from it.

ROS-free.  :func:`expand` is the one entry point the runner calls: with a plant block in
the flat parameters it returns them with the chosen observer's explicit parameters
derived (and the ``plant.*`` keys consumed), the map to the coordinates an observer runs
in included (``global_norm.chain_map``: observers/chain_map.py).  Derived values are returned, never stored back: a runtime change of a tuning value
(``single_delay.k``) re-derives everything that depends on it.
"""
from __future__ import annotations

from typing import Any, Mapping

from ..core.errors import ConfigError
from ..observers import REGISTRY
from .block import PLANT_PARAMS, PREFIX, Plant, given, resolve_plant
from .derive import DERIVES, Derivation, derive


def conflicts(type_name: str, section: Mapping[str, Any]) -> list[str]:
    """The parameters of ``section`` (the observer's own, short names) that the plant block
    would derive and that are set to something else than their default."""
    defaults = {p.name: p.default for p in REGISTRY[type_name].PARAMS}
    return [k for k in DERIVES.get(type_name, ()) if k in section
            and section[k] not in (None, [], ()) and section[k] != defaults.get(k)]


def expand(flat: Mapping[str, Any]) -> dict[str, Any]:
    """The flat parameters with the derived ones; see the module doc.

    Without a plant block: the parameters unchanged (minus empty ``plant.*`` defaults the
    node declares).  ConfigError for a bad plant, a plant outside the
    observer's class, or a parameter given both ways."""
    out = {k: v for k, v in flat.items() if not k.startswith(PREFIX)}
    if not given(flat):
        return out
    type_name = flat.get("observer.type")
    if not isinstance(type_name, str) or type_name not in REGISTRY:
        return out                         # split() refuses a missing or unknown type
    plant = resolve_plant(flat)
    section = {k[len(type_name) + 1:]: v for k, v in flat.items()
               if k.startswith(type_name + ".")}
    both = conflicts(type_name, section)
    if both:
        raise ConfigError(f"{type_name}.{both[0]}", "given explicitly and derived from the "
                          "plant block (plant.f, plant.h): give one or the other")
    d = derive(type_name, plant, section)
    out.update({f"{type_name}.{k}": v for k, v in d.params.items()})
    return out


__all__ = ["DERIVES", "Derivation", "PLANT_PARAMS", "Plant", "derive", "expand", "given",
           "resolve_plant"]
