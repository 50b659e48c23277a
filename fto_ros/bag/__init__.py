"""rosbag2 (MCAP) file I/O: no rclpy, no ROS install needed.

- :class:`BagWriter` writes ``Float64MultiArray``, ``JointState``, ``Clock`` and
  ``DiagnosticArray`` messages from plain Python values, ready CDR bytes, or blocks of
  many messages at once (mcap_write.py, our own MCAP writer).
- mcap_scan.py reads a bag's raw payloads fast through its MCAP indexes, cdr.py decodes
  and encodes fixed-layout messages in blocks (numpy).
- :class:`BagReader` (rosbags) / :func:`read_messages` yield ``(topic, t_ns, msg)`` in
  log-time order; :func:`list_topics` / :func:`bag_info` summarise a bag.
- Every failure raises :class:`BagError` naming the path and the problem.
"""
from __future__ import annotations

from .reader import (BagError, BagInfo, BagReader, TopicInfo, bag_info, list_topics,
                     read_messages)
from .writer import BagWriter

__all__ = ["BagError", "BagInfo", "BagReader", "BagWriter", "TopicInfo", "bag_info",
           "list_topics", "read_messages"]
