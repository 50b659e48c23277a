"""How the runner classifies the time of every measurement: one owner of time.

Given the stamp of the last accepted sample, a new stamp t is

- ``FIRST``: nothing accepted since the (re)start;
- ``STEP``: 0 < t - t_last <= the limit (``time.max_gap``, or the observer's ``max_step``
  if shorter): the observer bridges it exactly, with bounded work;
- ``REJECT``: ``repeated_stamp`` (t == t_last), ``stamp_too_close`` (closer than the
  observers' 1 us clock), ``stamp_backwards`` (back by at most ``time.jump_threshold``,
  or by any amount when ``time.reset_on_jump`` is off);
- a **discontinuity**: forward beyond the limit (a pause, a dropped stretch) or back
  beyond the threshold (a bag loop, a simulator reset).  One stamp alone cannot tell a
  resumed stream from a junk stamp, so it is held (``HOLD``), not acted on: if the next
  stamp continues the old timeline, the held one was junk (rejected as
  ``stamp_jump_unconfirmed``); if it continues the held one (0 < t - t_held <= the limit),
  the jump is confirmed (``CONFIRM``): the runner restarts the observer once (``gap`` or
  ``time_jump``), starts it on the held sample and goes on with this one.  A stamp that
  continues neither replaces the held one.  So a stream with junk stamps mixed in never
  restarts at all, and a real jump restarts once, one sample late.

Compiled (core/jit.py); pure bookkeeping, the runner acts on the verdicts.  ROS-free.
"""
from __future__ import annotations

from ..core.jit import jit
from ..core.reasons import CODE, RESTART_CODE
from ..observers.kernel import quanta

FIRST, STEP, REJECT, HOLD, CONFIRM = 0, 1, 2, 3, 4
_TOO_CLOSE, _REPEATED, _BACKWARDS = CODE["stamp_too_close"], CODE["repeated_stamp"], \
    CODE["stamp_backwards"]
GAP, TIME_JUMP = RESTART_CODE["gap"], RESTART_CODE["time_jump"]


@jit
def classify(t, t_last, held, t_held, held_kind, limit, jump_threshold, reset_on_jump):
    """(verdict, detail): detail is the rejection code (REJECT) or the restart code (HOLD,
    CONFIRM).  ``t_last`` is nan when nothing was accepted since the (re)start; ``held``
    whether a sample is held (at ``t_held``, restart ``held_kind``)."""
    if t_last != t_last:
        return FIRST, 0
    dt = t - t_last
    if 0.0 < dt <= limit:
        if quanta(dt) == 0:
            return REJECT, _TOO_CLOSE
        return STEP, 0
    if dt == 0.0:
        return REJECT, _REPEATED
    if dt < 0.0 and (not reset_on_jump or -dt <= jump_threshold):
        return REJECT, _BACKWARDS
    # a discontinuity: forward beyond the limit, or back beyond the threshold
    if held and 0.0 < t - t_held <= limit and quanta(t - t_held) > 0:
        return CONFIRM, held_kind
    return HOLD, GAP if dt > 0.0 else TIME_JUMP
