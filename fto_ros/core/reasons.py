"""Every reason a sample is rejected or an observer restarted, as a small integer.

Compiled code cannot pass strings: a kernel returns one of these codes, the runner counts
per code, and the names come back here for /diagnostics, metrics and logs.  One table for
the whole package (the runner's checks, the timeline, the gate, every observer family), so
no two places can spell a reason differently.  Add a reason at the end of its group.

ROS-free.
"""
from __future__ import annotations

#: rejection reasons, code = index (0 means accepted)
REJECTIONS = (
    "",
    # the runner's value checks (messages -> samples)
    "measurement_not_an_array", "measurement_wrong_length", "measurement_not_numeric",
    "measurement_non_finite", "measurement_implausible", "bad_stamp",
    "input_not_an_array", "input_wrong_length", "input_not_numeric", "input_non_finite",
    "input_implausible", "input_bad_stamp",
    # the timeline and the input
    "stamp_too_close", "repeated_stamp", "stamp_backwards", "stamp_jump_unconfirmed",
    "missing_input", "stale_input", "outlier",
    # what an observer cannot use (its state is left untouched)
    "step_too_long", "non_finite_model_term", "non_finite_estimate", "non_finite_prediction",
    "singular_step", "measurement_older_than_prediction", "singular_jacobian",
    "singular_innovation_covariance", "model_undefined_at_estimate", "non_finite_differentiator",
    "non_finite_gain", "non_finite_model", "step_spans_too_many_windows", "non_finite_gamma_1",
    # the runner's verdict on an observer's output (the observer restarts)
    "observer_error", "estimate_implausible",
    # found by the node or the replay before the runner (message intake)
    "zero_stamp", "future_stamp", "waiting_for_clock", "disabled",
    "joint_states_joint_missing", "joint_states_position_missing",
    "joint_states_velocity_missing", "joint_states_effort_missing",
    "joint_states_duplicate_joint",
)
CODE = {name: i for i, name in enumerate(REJECTIONS)}

#: restart reasons, code = index
RESTARTS = ("service", "enable", "reconfigure", "set_state", "gap", "time_jump",
            "observer_error", "non_finite_state", "estimate_implausible", "reacquire",
            "other")          # "other": a reason the caller names (counted by name in Python)
RESTART_CODE = {name: i for i, name in enumerate(RESTARTS)}
#: restarts a person asked for: they clear the health window
REQUESTED = ("service", "enable", "reconfigure", "set_state")
#: restarts that mean the observer failed (/diagnostics ERROR while in the window)
FAILURES = ("observer_error", "non_finite_state", "estimate_implausible")


def code(name: str) -> int:
    """The code of rejection reason ``name`` (KeyError for an unknown one: a typo)."""
    return CODE[name]


def name(code_: int) -> str:
    """The rejection reason of a code."""
    return REJECTIONS[code_]
