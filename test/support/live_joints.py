"""The live per-joint node's side for the tests (test_node_joints_live.py,
test_faults_live.py): the params files of a 3-joint DC-motor arm, the node started on them,
and a driver that collects whole output JointStates and every /diagnostics status."""
from __future__ import annotations

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from live_node import NODE, ROOT, Driver, NodeProcess

JOINTS = ["j1", "j2", "j3"]
A1 = "a1=[35, 30, 40]"


def joint_params(tmp, tuning: str, extra: dict | None = None) -> list:
    """The params files of a 3-joint DC-motor arm (config/dc_motor_plant.yaml, a tuning
    file, the per-joint settings)."""
    own = {"source": "joint_states", "joints": JOINTS,
           "plant": {"constants": ["b0=40", "b1=15", A1, "a2=1", "a3=36.4", "a4=200"]},
           "joint_states": {"output_joints": []},
           "estimated_joint_states": {"joint_names": [], "position_states": [],
                                      "velocity_states": [], "effort_states": []},
           "diagnostics": {"period": 0.2, "expected_rate": 0.0},
           "qos": {"depth": 1000}}     # a loaded machine's node falls behind, loses none
    for k, v in (extra or {}).items():
        own.setdefault(k, {}).update(v) if isinstance(v, dict) else own.__setitem__(k, v)
    path = tmp / "joints.yaml"
    path.write_text(yaml.safe_dump({"observer_node": {"ros__parameters": own}}))
    return [ROOT / "config/dc_motor_plant.yaml", ROOT / f"config/{tuning}.yaml", path]


def start(tmp, files, domain):
    args = []
    for f in files:
        args += ["--params-file", str(f)]
    return NodeProcess(tmp, domain, None, *args)


def connect(driver, node) -> None:
    """Wait for the node (its first start builds and caches the kernels of the joints: up
    to a minute on a loaded machine) and its outputs."""
    driver.wait_for(lambda: driver.pub_js.get_subscription_count() > 0, 120,
                    "the node's subscription", node)
    driver.wait_connected(node, [driver.pub_js], outputs=("estimated_joint_states",))


class JointDriver(Driver):
    """The test's node, collecting whole output JointStates and every /diagnostics status."""

    def __init__(self, domain):
        super().__init__(domain, outputs=())
        rel = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        for key in ("joint_out", "state_out", "diag_all"):
            self.received[key] = []
        self._collect(JointState, "joint_out", NODE + "/estimated_joint_states", rel,
                      lambda m: (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, list(m.name),
                                 np.array(m.position), np.array(m.velocity), np.array(m.effort)))
        self._collect(DiagnosticArray, "diag_all", "/diagnostics", 100,
                      lambda m: {st.name: dict({kv.key: kv.value for kv in st.values},
                                               level=str(st.level[0]), message=st.message)
                                 for st in m.status})

    def joint_status(self, name: str, timeout=10.0) -> dict:
        start = len(self.got("diag_all"))

        def find():
            for d in self.got("diag_all")[start:]:
                if name in d:
                    return d[name]
            return None
        return self.wait_for(find, timeout, f"the status {name}")
