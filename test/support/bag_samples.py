"""A sample bag for the bag tests (test/unit/bag/): every message type the package writes,
values at the edges of float64, a custom metadata entry; the type names and a stamp helper."""
from __future__ import annotations

import math
from pathlib import Path

from fto_ros.bag import BagWriter

F64 = "std_msgs/msg/Float64MultiArray"
JS = "sensor_msgs/msg/JointState"
CLOCK = "rosgraph_msgs/msg/Clock"
DIAG = "diagnostic_msgs/msg/DiagnosticArray"
VALUES = [0.0, -0.0, 1.5, -2.25, 1e-300, 1.7976931348623157e308, math.pi, -1.0 / 3.0]


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def write_sample_bag(path: Path, **kw) -> None:
    with BagWriter(path, custom_data={"k": "v", "json": '{"a": 1}'}, **kw) as bag:
        bag.clock(0)
        bag.float_array("/sys/y", 0, VALUES)
        bag.joint_state("/sys/joint_states", 0, 0, ["joint1"], position=[0.5])
        bag.clock(1_000_000)
        bag.joint_state("/sys/joint_states", 1_000_000, 999_999_999_999, ["a", "b"],
                        position=[1.0, 2.0], velocity=[], effort=[-3.0, 4.5], frame_id="base")
        bag.float_array("/sys/empty", 1_000_000, [])
        bag.diagnostics("/diagnostics", 2_500_000_000, [
            {"level": "WARN", "name": "obs: status", "message": "converging",
             "hardware_id": "dc_motor", "values": {"samples": 12, "residual": 1.5e-3}},
            {"level": 0, "name": "second", "message": "", "values": [("x", "y")]},
        ], stamp_ns=2_400_000_000)
        bag.clock(2_500_000_000)
