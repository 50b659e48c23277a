"""How the runner classifies the time of every measurement: one owner of time.

Given the stamp of the last accepted sample, a new stamp t is

- ``first``: nothing accepted since the (re)start;
- ``step``: 0 < t - t_last <= the limit (``time.max_gap``, or the observer's
  ``max_step`` if shorter): the observer bridges it exactly, with bounded work;
- ``repeated_stamp`` (t == t_last), ``stamp_too_close`` (closer than the observers'
  1 us clock), ``stamp_backwards`` (back by at most ``time.jump_threshold``, or by
  any amount when ``time.reset_on_jump`` is off): rejected;
- a **discontinuity**: forward beyond the limit (a pause, a dropped stretch) or back
  beyond the threshold (a bag loop, a simulator reset).  One stamp alone cannot tell a
  resumed stream from a junk stamp, so it is *held*, not acted on: if the next stamp
  continues the old timeline, the held one was junk (rejected as
  ``stamp_jump_unconfirmed``); if it continues the held one (0 < t - t_held <= the
  limit), the jump is confirmed: the runner restarts the observer once (``gap`` or
  ``time_jump``), starts it on the held sample and goes on with this one.  A stamp
  that continues neither replaces the held one.  So a stream with junk stamps mixed in
  never restarts at all, and a real jump restarts once, one sample late.

ROS-free; pure bookkeeping (the runner acts on the verdicts).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..core.discretize import quanta

FIRST, STEP, REJECT, HOLD, CONFIRM = "first", "step", "reject", "hold", "confirm"


@dataclass
class Held:
    """A sample held at a discontinuity, with the input that was current then."""

    t: float
    y: Any
    u: Any
    t_input: float | None
    kind: str          # the restart reason if confirmed: "gap" or "time_jump"
    inputs: list = field(default_factory=list)   # (t, u) received while it was held


def classify(t: float, t_last: float | None, held: Held | None, limit: float,
             jump_threshold: float, reset_on_jump: bool) -> tuple[str, str | None]:
    """(verdict, detail) for a sample at t: detail is the rejection reason (REJECT) or
    the restart reason (HOLD, CONFIRM)."""
    if t_last is None:
        return FIRST, None
    dt = t - t_last
    if 0.0 < dt <= limit:
        if quanta(dt) == 0:
            return REJECT, "stamp_too_close"
        return STEP, None
    if dt == 0.0:
        return REJECT, "repeated_stamp"
    if dt < 0.0 and (not reset_on_jump or -dt <= jump_threshold):
        return REJECT, "stamp_backwards"
    # a discontinuity: forward beyond the limit, or back beyond the threshold
    if held is not None and 0.0 < t - held.t <= limit and quanta(t - held.t) > 0:
        return CONFIRM, held.kind
    return HOLD, "gap" if dt > 0 else "time_jump"
