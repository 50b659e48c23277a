"""ModelSpec for plants driven by an unknown input zeta(t) (ROS-free).

``fto-simulate`` writes the true zeta(t) on ``/<system>/true_unknown_input`` for such a
model (at the same instants as ``/<system>/true_state``) and can add a deterministic
output disturbance (``--output-disturbance``), e.g. the noise of Fridman, Levant & Davila's
Example 1.  ``system_name`` (when not empty) is the topic namespace, so a variant of a
plant (``dc_motor_load``) records on the same topics as the plant (``/dc_motor/...``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .simulate import ModelSpec


@dataclass(frozen=True)
class UnknownInputModelSpec(ModelSpec):
    """A :class:`ModelSpec` whose right-hand side contains ``D zeta(t)``.

    Attributes (besides ModelSpec's):
        unknown_input: ``t -> zeta(t)`` (length q), the ground truth the rhs uses.
        unknown_input_names: names of the zeta components.
        unknown_input_description: formula of zeta(t).
        output_disturbance: ``t -> deterministic measurement disturbance`` (length p),
            added by ``fto-simulate --output-disturbance``; None if the model has none.
        output_disturbance_description: its formula.
        system_name: topic namespace (empty: ``name``).
    """

    unknown_input: Callable[[float], np.ndarray] | None = None
    unknown_input_names: tuple[str, ...] = field(default=())
    unknown_input_description: str = ""
    output_disturbance: Callable[[float], np.ndarray] | None = None
    output_disturbance_description: str = ""
    system_name: str = ""

    @property
    def system(self) -> str:
        """Topic namespace: ``system_name`` or ``name``."""
        return self.system_name or self.name
