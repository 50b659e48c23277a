"""The DC-motor joint of ``dc_motor`` with an unknown load torque (ROS-free).

Same plant, parameters, initial state and voltage profile as :mod:`fto_ros.models.dc_motor`
(Mazenc & Malisoff 2022, eq. 65), plus an unknown load torque tau_L(t) opposing the motor:

    q'     = q_dot
    q_dot' = b1 I - a1 sin q - a2 q_dot - b1 tau_L(t)
    I'     = b0 V - a3 q_dot - a4 I,          y = q

(the paper's model has torque constant 1, b1 = 1/M: the motor torque is I, so a load torque
tau_L, in the same units, enters as -b1 tau_L; D = (0, -b1, 0)).  Load profile, smooth and
bounded, comparable to the motor's torque scale (|I| ~ 1, gravity a1/b1 = 2.33):

    tau_L(t) = 0.4 s((t - 1.5) / 0.15) + 0.15 sin(2 pi 0.8 t),   s(v) = (1 + tanh v) / 2

a load of 0.4 picked up smoothly around t = 1.5 s plus a 0.8 Hz oscillation;
|tau_L| <= 0.55, |tau_L'| <= 1.7 (s^-1), |tau_L''| <= 10.6 (s^-2).

Registered as ``dc_motor_load``; it records on the dc_motor topics (``/dc_motor/...``) plus
``/dc_motor/true_unknown_input`` ([tau_L]).
"""
from __future__ import annotations

import math
from dataclasses import asdict
from typing import Mapping

import numpy as np

from . import dc_motor
from .dc_motor import DCMotorParams
from .simulate import Rhs
from .unknown_input import UnknownInputModelSpec

#: bounds of the load and its first two derivatives (see the module docstring; measured
#: on a 1e-4 s grid over 0..10 s: 0.550, 1.62, 10.57)
LOAD_BOUND, LOAD_DERIVATIVE_BOUND, LOAD_SECOND_DERIVATIVE_BOUND = 0.55, 1.7, 10.6


def load_torque(t: float) -> np.ndarray:
    """tau_L(t) = 0.4 s((t - 1.5)/0.15) + 0.15 sin(2 pi 0.8 t), as a length-1 array."""
    return np.array([0.2 * (1.0 + math.tanh((t - 1.5) / 0.15))
                     + 0.15 * math.sin(2.0 * math.pi * 0.8 * t)])


def make_rhs(params: Mapping[str, float] | DCMotorParams | None = None) -> Rhs:
    """The dc_motor right-hand side plus the load torque term -b1 tau_L(t)."""
    p = params if isinstance(params, DCMotorParams) else DCMotorParams.from_mapping(params)
    base = dc_motor.make_rhs(p)
    b1 = p.b1

    def f(t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        dx = base(t, x, u)
        dx[1] -= b1 * (0.2 * (1.0 + math.tanh((t - 1.5) / 0.15))
                       + 0.15 * math.sin(2.0 * math.pi * 0.8 * t))
        return dx

    return f


SPEC = UnknownInputModelSpec(
    name="dc_motor_load",
    description="DC-motor joint (Mazenc & Malisoff 2022, eq. 65) with an unknown load torque "
                "tau_L(t) (records on the /dc_motor topics)",
    state_names=dc_motor.STATE_NAMES,
    input_names=("V",),
    output_names=("q",),
    default_params=asdict(dc_motor.DEFAULT_PARAMS),
    make_rhs=make_rhs,
    output=dc_motor.output,
    default_x0=dc_motor.DEFAULT_X0,
    default_input=dc_motor.default_voltage,
    input_description=dc_motor.SPEC.input_description,
    uncertainty=dc_motor.uncertainty,
    uncertainty_description=dc_motor.SPEC.uncertainty_description,
    joint_names=("joint1",),
    unknown_input=load_torque,
    unknown_input_names=("tau_L",),
    unknown_input_description="tau_L(t) = 0.4 s((t - 1.5)/0.15) + 0.15 sin(2 pi 0.8 t), "
                              "s(v) = (1 + tanh v)/2, entering q_dot' as -b1 tau_L",
    system_name="dc_motor",
)
