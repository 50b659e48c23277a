"""Plants used for examples, simulation and bag generation (ROS-free).

``MODELS`` maps a model name to its :class:`~fto_ros.models.simulate.ModelSpec`.
To add a plant, write ``fto_ros/models/<name>.py`` defining ``SPEC`` and add one
entry below.
"""
from __future__ import annotations

from . import canonical_form, dc_motor
from . import dc_motor_load, fld_examples
from . import possieri_example
from . import cubic_escape
from .simulate import ModelSpec, SimulationResult, simulate
from ..core.errors import UnknownName

MODELS: dict[str, ModelSpec] = {
    **{m.name: m for m in (cubic_escape.CUBIC_ESCAPE_SPEC, cubic_escape.VAN_DER_POL_SPEC)},
    **{m.name: m for m in (fld_examples.EXAMPLE1_SPEC, fld_examples.EXAMPLE2_SPEC, dc_motor_load.SPEC)},
    dc_motor.SPEC.name: dc_motor.SPEC,
    possieri_example.SPEC.name: possieri_example.SPEC,
    canonical_form.DOUBLE_INTEGRATOR_SPEC.name: canonical_form.DOUBLE_INTEGRATOR_SPEC,
    canonical_form.THIRD_ORDER_SPEC.name: canonical_form.THIRD_ORDER_SPEC,
}


def get_model(name: str) -> ModelSpec:
    """The registered spec ``name``, or KeyError whose message lists the known models."""
    try:
        return MODELS[name]
    except KeyError:
        raise UnknownName(f"unknown model {name!r}; known models: {', '.join(sorted(MODELS))}") \
            from None


__all__ = ["MODELS", "ModelSpec", "SimulationResult", "get_model", "simulate"]
