"""core/cdr.py, the one CDR codec, byte for byte against rosbags' serialiser and read back
by rclpy's deserialiser (the references), for every layout kind the node and the replay
publish: labelled and plain Float64MultiArrays of 0..5 values, JointStates with empty and
full arrays, frame_ids and names whose lengths move every alignment; the bulk decoders
against the per-message ones.  (The JointState decoder's own cases:
test_cdr_joint_state.py.)"""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from fto_ros.bag.reader import jazzy_typestore
from fto_ros.core.cdr import (F64_ARRAY, JOINT_STATE, FloatDecoder, FloatEncoder,
                              JointStateDecoder, decode_float_block, f64_data_at, float_block,
                              joint_state_block)
from fto_ros.core.errors import DecodeError

TS = jazzy_typestore()
T = TS.types
RNG = np.random.default_rng(7)
LABELS = [None, ["x"], ["q", "q_dot", "zeta"], ["joint_a1/q", "a", "bb", "ccc", "dddd"]]
NAMES = [[], ["a"], ["joint_a1", "joint_a2"], ["é", "bb", "ccc", "dddd", "eeeee"]]


def _rosbags_f64(x, labels) -> bytes:
    dims = [T["std_msgs/msg/MultiArrayDimension"](label=lb, size=1, stride=1)
            for lb in labels or ()]
    msg = T[F64_ARRAY](layout=T["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0),
                       data=np.asarray(x, dtype=np.float64))
    return bytes(TS.serialize_cdr(msg, F64_ARRAY))


def _rosbags_js(names, sec, nsec, arrays, frame) -> bytes:
    msg = T[JOINT_STATE](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                        frame_id=frame),
        name=list(names), position=arrays[0], velocity=arrays[1], effort=arrays[2])
    return bytes(TS.serialize_cdr(msg, JOINT_STATE))


@pytest.mark.parametrize("labels", LABELS, ids=str)
def test_float_arrays_are_rosbags_bytes_and_read_back(labels):
    for n in ([len(labels)] if labels else range(6)):
        x = RNG.normal(size=(4, n))
        block = float_block(n, labels)(x)
        one = FloatEncoder(n, labels)
        dec = FloatDecoder()
        for row, payload in zip(x, block):
            ref = _rosbags_f64(row, labels)
            assert payload.tobytes() == ref == one.encode(row)
            back = deserialize_message(ref, Float64MultiArray)
            assert list(back.data) == row.tolist()
            assert [d.label for d in back.layout.dim] == list(labels or [])
            assert dec.decode(ref).tolist() == row.tolist()
        np.testing.assert_array_equal(decode_float_block(block), x)
        np.testing.assert_array_equal(decode_float_block([p.tobytes() for p in block]), x)


@pytest.mark.parametrize("frame", ["", "w", "base_link", "odom_12"])
@pytest.mark.parametrize("names", NAMES, ids=len)
def test_joint_states_are_rosbags_bytes_and_read_back(names, frame):
    k = len(names)
    for sizes in ((k, k, k), (k, 0, k), (0, 0, 0), (0, k, 0)):
        sec, nsec = RNG.integers(-2 ** 31, 2 ** 31 - 1, 3), RNG.integers(0, 2 ** 32 - 1, 3)
        arrays = [RNG.normal(size=(3, s)) for s in sizes]
        block = joint_state_block(names, sizes, frame)(sec, nsec, *arrays)
        for i, payload in enumerate(block):
            mine = [a[i] for a in arrays]
            ref = _rosbags_js(names, int(sec[i]), int(nsec[i]), mine, frame)
            assert payload.tobytes() == ref
            back = deserialize_message(ref, JointState)
            assert (back.header.stamp.sec, back.header.stamp.nanosec, back.header.frame_id,
                    list(back.name)) == (sec[i], nsec[i], frame, list(names))
        runs = JointStateDecoder().decode_block(block)          # the matrix: one run
        assert len(runs) == 1
        got_sec, got_nsec, js = runs[0]
        assert got_sec.tolist() == sec.tolist() and got_nsec.tolist() == nsec.tolist()
        for got, want in zip((js.position, js.velocity, js.effort), arrays):
            np.testing.assert_array_equal(got, want)


def test_a_matrix_of_mixed_layouts_is_split_into_runs():
    a = joint_state_block(["ab"], (1, 0, 0))([1, 2], [0, 0], [[1.0], [2.0]], None, None)
    b = joint_state_block(["cd"], (1, 0, 0))([3], [0], [[3.0]], None, None)   # same length
    runs = JointStateDecoder().decode_block(np.concatenate([a, b, a[:1]]))
    assert [(js.name, s.tolist()) for s, _, js in runs] == [(("ab",), [1, 2]), (("cd",), [3]),
                                                            (("ab",), [1])]


def test_odd_float_payloads_are_decode_errors_or_left_to_the_caller():
    good = _rosbags_f64([1.0, 2.0], ["a", "b"])
    dec = FloatDecoder()
    for bad in (b"", b"\x00\x01", b"\x00\x00\x00\x00" + good[4:], good[:-3], good[:9],
                b"\x00\x01\x00\x00" + b"\xff" * 7):
        with pytest.raises(DecodeError):
            dec.decode(bad)
        with pytest.raises(DecodeError):
            f64_data_at(bad)
    assert dec.decode(good).tolist() == [1.0, 2.0]       # the decoder is still good
    other = _rosbags_f64([1.0, 2.0, 3.0], None)
    assert decode_float_block([good, other]) is None     # lengths differ: per message
    assert decode_float_block([good, _rosbags_f64([1.0, 2.0], ["a", "c"])]) is None
