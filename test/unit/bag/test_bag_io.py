"""rosbag2 (MCAP) writer/reader helpers (fto_ros/bag/): round trips of every message type,
topics and custom data, compression and filters, write order, rclpy's own decoding, and the
errors (missing, truncated, corrupt bags; existing outputs; validation).  No ROS needed.
(The fast paths: test_bag_fast_paths.py; fto-simulate: test/unit/cli/test_simulate_cli.py.)"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bag_samples import CLOCK, DIAG, F64, JS, VALUES, stamp_ns, write_sample_bag
from fto_ros.bag import BagError, BagReader, BagWriter, bag_info, list_topics, read_messages
from fto_ros.core.output_dir import OutputError, OutputExists

ROOT = Path(__file__).resolve().parents[3]


def test_round_trip_all_message_types(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path)
    assert (path / "metadata.yaml").is_file() and list(path.glob("*.mcap"))
    msgs = list(read_messages(path))
    assert [(topic, t) for topic, t, _ in msgs] == [
        ("/clock", 0), ("/sys/y", 0), ("/sys/joint_states", 0),
        ("/clock", 1_000_000), ("/sys/joint_states", 1_000_000), ("/sys/empty", 1_000_000),
        ("/diagnostics", 2_500_000_000), ("/clock", 2_500_000_000)]
    clk0, y, js0, clk1, js1, empty, diag, clk2 = (m for _, _, m in msgs)
    assert stamp_ns(clk0.clock) == 0 and stamp_ns(clk1.clock) == 1_000_000
    assert stamp_ns(clk2.clock) == 2_500_000_000
    assert clk2.clock.sec == 2 and clk2.clock.nanosec == 500_000_000
    assert y.__msgtype__ == F64 and y.data.dtype == np.float64
    assert y.data.tolist() == VALUES  # bit-exact
    assert math.copysign(1.0, y.data[1]) == -1.0
    assert list(empty.data) == []
    assert js0.name == ["joint1"] and js0.position.tolist() == [0.5]
    assert len(js0.velocity) == 0 and len(js0.effort) == 0
    assert stamp_ns(js1.header.stamp) == 999_999_999_999 and js1.header.frame_id == "base"
    assert js1.name == ["a", "b"] and js1.position.tolist() == [1.0, 2.0]
    assert js1.effort.tolist() == [-3.0, 4.5] and len(js1.velocity) == 0
    assert stamp_ns(diag.header.stamp) == 2_400_000_000
    s0, s1 = diag.status
    assert (s0.level, s0.name, s0.message, s0.hardware_id) == (1, "obs: status", "converging",
                                                               "dc_motor")
    assert [(kv.key, kv.value) for kv in s0.values] == [("samples", "12"), ("residual", "0.0015")]
    assert (s1.level, s1.name, [(kv.key, kv.value) for kv in s1.values]) == (0, "second",
                                                                             [("x", "y")])


def test_topics_info_and_custom_data(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path)
    assert list_topics(path) == {
        "/clock": (CLOCK, 3), "/diagnostics": (DIAG, 1), "/sys/empty": (F64, 1),
        "/sys/joint_states": (JS, 2), "/sys/y": (F64, 1)}
    info = bag_info(path)
    assert info.message_count == 8 and info.storage == "mcap"
    assert (info.start_ns, info.end_ns, info.duration_ns) == (0, 2_500_000_000, 2_500_000_000)
    assert info.custom_data == {"k": "v", "json": '{"a": 1}'}


def test_uncompressed_bag_and_filters(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path, compress=False)
    with BagReader(path) as bag:
        got = [(topic, t) for topic, t, _ in bag.messages(["/clock"], start_ns=1,
                                                          stop_ns=2_500_000_000)]
        assert got == [("/clock", 1_000_000)]
        with pytest.raises(BagError, match="no topic"):
            bag.messages(["/nope"])


def test_equal_log_times_keep_write_order_across_chunks(tmp_path):
    path = tmp_path / "bag"
    n = 20000  # several MCAP chunks
    with BagWriter(path) as bag:
        for k in range(n):
            bag.float_array("/a", k * 1000, [k])
            bag.float_array("/b", k * 1000, [-k])
    prev = None
    count = 0
    for topic, t, msg in read_messages(path):
        k = t // 1000
        expected = ("/a", k) if count % 2 == 0 else ("/b", -k)
        assert (topic, msg.data[0]) == expected
        assert prev is None or t >= prev
        prev = t
        count += 1
    assert count == 2 * n


def test_decodes_with_rclpy_when_available(tmp_path):
    """The CDR written here is what a ROS 2 Jazzy node deserializes."""
    pytest.importorskip("rclpy")
    try:
        from rclpy.serialization import deserialize_message
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
    except ImportError as err:  # ROS libraries not loadable here
        pytest.skip(f"ROS piece missing: rclpy messages unavailable: {err}")
    from rosbags.rosbag2 import Reader
    types = {F64: Float64MultiArray, JS: JointState, CLOCK: Clock, DIAG: DiagnosticArray}
    path = tmp_path / "bag"
    write_sample_bag(path)
    with Reader(path) as reader:
        decoded = [(c.topic, deserialize_message(bytes(raw), types[c.msgtype]))
                   for c, _, raw in reader.messages()]
    assert list(decoded[1][1].data) == VALUES
    assert list(decoded[4][1].effort) == [-3.0, 4.5]
    assert decoded[6][1].status[0].values[1].value == "0.0015"


# ------------------------------------------------------------------- errors
def test_missing_path(tmp_path):
    with pytest.raises(BagError, match="does not exist") as exc:
        read_messages(tmp_path / "nope")
    assert str(tmp_path / "nope") in str(exc.value)
    with pytest.raises(BagError):
        bag_info(tmp_path / "nope")


def test_directory_that_is_not_a_bag(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a rosbag2 bag") as exc:
        BagReader(tmp_path)
    assert str(tmp_path) in str(exc.value)
    other = tmp_path / "notes.txt"
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        list_topics(other)


@pytest.mark.parametrize("keep", [0.0, 0.3, 0.9, 0.999])
def test_truncated_mcap(tmp_path, keep):
    path = tmp_path / "bag"
    write_sample_bag(path)
    mcap = next(path.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * keep)])
    with pytest.raises(BagError) as exc:
        list(read_messages(path))
    assert str(path) in str(exc.value) and "Traceback" not in str(exc.value)


def test_corrupt_chunk_and_metadata(tmp_path):
    path = tmp_path / "bag"
    with BagWriter(path) as bag:
        for k in range(5000):
            bag.float_array("/a", k, np.sin(np.arange(8) * k))
    mcap = next(path.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    mid = len(data) // 3
    data[mid:mid + 64] = b"\xa5" * 64
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match="corrupt") as exc:
        list(read_messages(path))
    assert str(path) in str(exc.value)
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    with pytest.raises(BagError, match="cannot open bag"):
        bag_info(path)


def test_existing_output_and_overwrite(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path)
    with pytest.raises(OutputExists, match="exists already") as exc:
        BagWriter(path).open()
    assert str(path) in str(exc.value)
    with BagWriter(path, overwrite=True) as bag:
        bag.clock(5)
    assert list_topics(path) == {"/clock": (CLOCK, 1)}
    # a directory that is not a bag is never deleted
    src = tmp_path / "src"
    (src / "pkg").mkdir(parents=True)
    (src / "setup.py").write_text("")
    with pytest.raises(OutputError, match="refusing to replace"):
        BagWriter(src, overwrite=True).open()
    assert (src / "setup.py").exists()
    # an empty directory is fine
    empty = tmp_path / "empty"
    empty.mkdir()
    with BagWriter(empty, overwrite=True) as bag:
        bag.clock(1)


def test_writer_validation(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        with pytest.raises(BagError, match=">= 0"):
            bag.clock(-1)
        with pytest.raises(BagError, match="integer number of nanoseconds"):
            bag.float_array("/a", 0.5, [1.0])
        bag.float_array("/a", 1, [1.0])
        with pytest.raises(BagError, match="already has type"):
            bag.clock(2, topic="/a")
        with pytest.raises(BagError, match="2 values for 1 joint"):
            bag.joint_state("/j", 1, 1, ["j"], position=[1.0, 2.0])
        with pytest.raises(BagError, match="unknown level"):
            bag.diagnostics("/diagnostics", 1, [{"level": "FINE"}])
        with pytest.raises(BagError, match="absolute"):
            bag.float_array("relative", 1, [1.0])
    with pytest.raises(BagError, match="not open"):
        BagWriter(tmp_path / "other").float_array("/a", 0, [1.0])


def test_failed_write_removes_half_written_bag(tmp_path):
    path = tmp_path / "bag"
    with pytest.raises(RuntimeError):
        with BagWriter(path) as bag:
            bag.clock(1)
            raise RuntimeError("boom")
    assert not path.exists()


def test_bag_layer_imports_no_rclpy():
    code = ("import sys, fto_ros.bag, fto_ros.cli.simulate; "
            "sys.exit(1 if 'rclpy' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT).returncode == 0
