"""The plants the naive references run on, written from their params files' equations
(config/<system>_plant.yaml; the constants are read from there), with the sample streams
the tests feed: the DC motor of Mazenc & Malisoff 2022 Section V, the double integrator of
Holloway & Krstic 2019 Example 1, ...

Each ``*_stream`` returns (t, x, y, u): stamps, the true state, the measured output and the
held input at every stamp.
"""
from __future__ import annotations

import numpy as np

import naive_support as NS

DC = NS.plant_constants("dc_motor_plant")


def dc_motor_linear():
    """(A, B, C) of the DC motor's linear part, states (q, q_dot, I), input V, output q;
    the gravity term -a1 sin(q) is the known output term F(y) on q_dot' (dc_motor_plant.yaml:
    q' = q_dot, q_dot' = b1 I - a1 sin q - a2 q_dot - b1 tau_L, I' = b0 V - a3 q_dot - a4 I)."""
    A = np.array([[0.0, 1.0, 0.0],
                  [0.0, -DC["a2"], DC["b1"]],
                  [0.0, -DC["a3"], -DC["a4"]]])
    B = np.array([[0.0], [0.0], [DC["b0"]]])
    C = np.array([[1.0, 0.0, 0.0]])
    return A, B, C


def dc_motor_F(y: np.ndarray) -> np.ndarray:
    """The known output term of the DC motor: (0, -a1 sin y, 0)."""
    return np.array([0.0, -DC["a1"] * np.sin(y[0]), 0.0])


def dc_motor_rhs(x, u, tau_L: float = 0.0):
    q, qd, i = x
    return np.array([qd,
                     DC["b1"] * i - DC["a1"] * np.sin(q) - DC["a2"] * qd - DC["b1"] * tau_L,
                     DC["b0"] * u[0] - DC["a3"] * qd - DC["a4"] * i])


def dc_motor_voltage(t: np.ndarray) -> np.ndarray:
    """An input that keeps the motor moving through its transient: a step, two sines."""
    return (4.0 + 3.0 * np.sin(7.0 * t) + 1.5 * np.cos(23.0 * t))[:, None]


def dc_motor_stream(t: np.ndarray, x0=(0.3, -2.0, 0.5), jump: tuple | None = None):
    """``jump`` = (sample j, dx): the state jumps by dx just before sample j (a collision:
    bags/dc_motor_collision adds 4 rad/s to q_dot)."""
    u = dc_motor_voltage(t)
    x = NS.simulate(dc_motor_rhs, np.asarray(x0, float), t, u)
    if jump is not None:
        j, dx = jump
        x[j:] = NS.simulate(dc_motor_rhs, x[j] + np.asarray(dx, float), t[j:], u[j:])
    return t, x, x[:, :1].copy(), u
