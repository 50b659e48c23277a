"""Input modes as sources: where the runner's samples come from and what is published for
them, chosen ONCE from the settings (:func:`make_source`); the node and the replay never
test the mode again (docs/sources.md).

- ``topics`` (topics.py): Float64MultiArray measured_output + input, receipt-stamped;
- ``joint_states`` (joint_states.py): the whole plant from a JointState;
- ``joints`` (joints.py): one observer per joint, every joint from one JointState.

The protocol is base.py's :class:`Source`, the outputs plan.py's :class:`OutputPlan`.
ROS-free.
"""
from __future__ import annotations

from .base import Fallback, Rows, Source, TopicIn
from .joint_states import WholeJointStateSource
from .joints import JointsSource
from .plan import OutputPlan, OutputSpec
from .topics import TopicsSource

__all__ = ["Fallback", "JointsSource", "OutputPlan", "OutputSpec", "Rows", "Source", "TopicIn",
           "TopicsSource", "WholeJointStateSource", "make_source"]


def make_source(runner, fallback: Fallback | None = None) -> Source:
    """The source of ``runner``'s settings: per joint with ``joints``, else by ``source``.
    ``fallback(payload, msgtype)``: the reference deserialiser for what the numpy codec
    does not take (base.py)."""
    if runner.joints:
        return JointsSource(runner, fallback)
    cls = {"topics": TopicsSource, "joint_states": WholeJointStateSource}[runner.settings["source"]]
    return cls(runner, fallback)
