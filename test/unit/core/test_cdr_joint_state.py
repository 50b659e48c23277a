"""core/cdr.py's JointState codec against rclpy's own (de)serialisation, the reference (no DDS).

Every decoded field must equal what ``rclpy.serialization.deserialize_message`` makes of
the same bytes (names, stamp, frame_id, the three arrays, including arrays shorter than
``name`` and empty ones at every alignment), and every encoded payload must deserialise
to exactly the values given.  A payload the decoder does not take raises ValueError,
never anything else.
"""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from fto_ros.core.cdr import CDR_LE, JointStateDecoder, JointStateEncoder, stamp_ns


def _msg(names, pos, vel, eff, sec=0, nanosec=0, frame_id=""):
    m = JointState(name=list(names), position=list(pos), velocity=list(vel), effort=list(eff))
    m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
    m.header.frame_id = frame_id
    return m


def _assert_equal(decoded, ref: JointState) -> None:
    assert decoded.sec == ref.header.stamp.sec and decoded.nanosec == ref.header.stamp.nanosec
    assert decoded.frame_id == ref.header.frame_id
    assert list(decoded.name) == list(ref.name)
    for field in ("position", "velocity", "effort"):
        got, want = getattr(decoded, field), np.array(getattr(ref, field), dtype=np.float64)
        assert got.dtype == np.float64 and got.shape == want.shape, field
        assert np.array_equal(got, want, equal_nan=True), field
    # duck-typed like an rclpy message (runner/messages.py reads these)
    assert decoded.header.stamp.sec == ref.header.stamp.sec
    assert decoded.header.frame_id == ref.header.frame_id


def _cases(seed: int = 7, n: int = 400):
    """Messages covering every padding: name and frame_id lengths 0..9, 0..9 names, each
    array 0..n+1 long (shorter than name, empty, longer), special values, stamp extremes."""
    rng = np.random.default_rng(seed)
    specials = [0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, 1.7976931348623157e308]
    stamps = [(0, 0), (-2**31, 0), (2**31 - 1, 999_999_999), (1_700_000_000, 123), (-1, 2**32 - 1)]
    for k in range(n):
        count = int(rng.integers(0, 10))
        names = ["j" * int(rng.integers(0, 10)) + str(i) * (k % 2) for i in range(count)]
        if k % 5 == 0 and names:
            names[0] = "épaule_ü"          # multi-byte UTF-8
        arrays = []
        for _ in range(3):
            length = int(rng.choice([0, count, max(count - 1, 0), count + 1]))
            vals = rng.normal(size=length) * 10.0 ** rng.integers(-5, 5)
            if length and k % 7 == 0:
                vals[0] = specials[k % len(specials)]
            arrays.append(vals)
        sec, nsec = stamps[k % len(stamps)]
        frame = "f" * int(rng.integers(0, 10))
        yield _msg(names, *arrays, sec=sec, nanosec=nsec, frame_id=frame)


def test_decoder_equals_rclpy_field_by_field():
    dec = JointStateDecoder()
    for m in _cases():
        payload = serialize_message(m)
        _assert_equal(dec.decode(payload), deserialize_message(payload, JointState))
    assert dec.parsed > 0


def test_repeated_layout_takes_the_fast_path_and_a_changed_one_is_parsed():
    names = [f"joint_a{i}" for i in range(1, 8)]
    dec = JointStateDecoder()
    stream = [_msg(names, np.arange(7) + k, np.arange(7) - k, [k] * 7, sec=k, nanosec=k) for k in range(50)]
    stream[20] = _msg(names[::-1], range(7), range(7), range(7), sec=20)      # reordered names
    stream[30] = _msg(names, range(7), [], range(7), sec=30)                 # velocity empty
    stream[31] = _msg(names, range(7), [], range(7), frame_id="x", sec=31)   # same length, frame
    first = None
    for m in stream:
        payload = serialize_message(m)
        got = dec.decode(payload)
        _assert_equal(got, deserialize_message(payload, JointState))
        if first is None:
            first = got
    # four layouts (the first, reordered, velocity empty, frame_id), each parsed once:
    # the decoder remembers the last four
    assert dec.parsed == 4 and dec.fast == 46
    assert dec.decode(serialize_message(stream[0])).name is first.name
    for k in range(JointStateDecoder.MEMORY):     # a fifth layout ... and four more
        dec.decode(serialize_message(_msg(names[:k + 1], [1.0], [], [])))
    dec.decode(serialize_message(stream[0]))
    assert dec.parsed == 4 + JointStateDecoder.MEMORY + 1   # the first one was forgotten


def test_padding_bytes_are_never_compared_or_read():
    """Publishers leave padding uninitialised: garbage there decodes the same, fast."""
    names = ["a", "bb", "ccc", "dddd"]
    m = _msg(names, [1.0, 2.0, 3.0], [4.0], [5.0, 6.0, 7.0, 8.0], sec=3, frame_id="ab")
    payload = bytearray(serialize_message(m))
    dec = JointStateDecoder()
    dec.decode(bytes(payload))
    ref = deserialize_message(bytes(payload), JointState)
    pads = _padding(names, "ab", (3, 1, 4))
    assert len(pads) == 7      # after frame_id, "a", "bb", "dddd"; before each array's values
    for fill in (0x00, 0xA5, 0xFF):
        dirty = bytearray(payload)
        for start, end in pads:
            dirty[start:end] = bytes([fill]) * (end - start)
        _assert_equal(dec.decode(bytes(dirty)), ref)
    assert dec.parsed == 1


def _padding(names, frame_id, sizes):
    """(start, end) of every padding run of a JointState payload (XCDR1 little endian)."""
    pos, out = 12, []

    def align(a):
        nonlocal pos
        pad = (4 - pos) % a
        if pad:
            out.append((pos, pos + pad))
        pos += pad
    for i, s in enumerate([frame_id, *names]):
        align(4)
        pos += 4 + len(s.encode()) + 1
        if i == 0:
            align(4)
            pos += 4          # the name count
    for k in sizes:
        align(4)
        pos += 4
        if k:
            align(8)
            pos += 8 * k
    return out


def test_unusual_or_broken_payloads_raise_value_error_only():
    m = _msg(["joint_a1", "joint_a2"], [1.0, 2.0], [3.0, 4.0], [5.0, 6.0], sec=5, frame_id="base")
    payload = serialize_message(m)
    dec = JointStateDecoder()
    dec.decode(payload)                       # a remembered layout must not mask any of these
    bad = [payload[:cut] for cut in range(len(payload) - 8)]   # rclpy pads the end: keep the values
    bad.append(b"\x00\x00\x00\x00" + payload[4:])                # big endian
    bad.append(b"\x00\x07\x00\x00" + payload[4:])                # XCDR2
    huge = bytearray(payload)
    huge[24:28] = (2**31).to_bytes(4, "little")                  # a name count past the end
    bad.append(bytes(huge))
    no_nul = bytearray(payload)
    no_nul[16 + 4] = ord("x")                                    # frame_id "base" not terminated
    bad.append(bytes(no_nul))
    not_utf8 = bytearray(payload)
    not_utf8[16] = 0xFF
    bad.append(bytes(not_utf8))
    for p in bad:
        with pytest.raises(ValueError):
            JointStateDecoder().decode(p)
        if len(p) != len(payload):
            with pytest.raises(ValueError):
                dec.decode(p)
    for p in bad[-3:]:                        # same length as the remembered layout
        with pytest.raises(ValueError):
            dec.decode(p)
    _assert_equal(dec.decode(payload), m)     # and the decoder still works


def test_encoder_payload_deserialises_to_the_values_given():
    rng = np.random.default_rng(3)
    for m in _cases(seed=11, n=200):
        names, frame = list(m.name), m.header.frame_id
        arrays = [np.array(getattr(m, f)) for f in ("position", "velocity", "effort")]
        enc = JointStateEncoder(names, tuple(len(a) for a in arrays), frame)
        for _ in range(2):                    # the reused buffer carries nothing over
            arrays = [rng.normal(size=len(a)) for a in arrays]
            st = m.header.stamp
            payload = enc.encode(st.sec, st.nanosec, *[a if len(a) else None for a in arrays])
            ref = deserialize_message(payload, JointState)
            want = _msg(names, *arrays, sec=st.sec, nanosec=st.nanosec, frame_id=frame)
            _assert_equal(JointStateDecoder().decode(payload), ref)
            _assert_equal(JointStateDecoder().decode(payload), want)


def test_encoder_matches_rosbags_bytes():
    """Byte for byte what rosbags' serialiser writes (zero padding)."""
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    for names, sizes in ((["joint1"], (1, 1, 1)), ([f"joint_a{i}" for i in range(7)], (7, 0, 7)),
                         ([], (0, 0, 0)), (["a", "bb", "ccc"], (3, 2, 0))):
        vals = [np.arange(k) * 0.5 + j for j, k in enumerate(sizes)]
        ours = JointStateEncoder(names, sizes, "base").encode(-4, 77, *[v if len(v) else None for v in vals])
        msg = T["sensor_msgs/msg/JointState"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=-4, nanosec=77),
                                            frame_id="base"),
            name=names, position=vals[0], velocity=vals[1], effort=vals[2])
        assert ours == bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
        assert ours[:4] == CDR_LE


def test_encoder_refuses_other_lengths_and_stamps():
    enc = JointStateEncoder(["a", "b"], (2, 0, 2))
    good = np.array([1.0, 2.0])
    for args in ((0, 0, good, None, [1.0]),            # effort too short
                 (0, 0, good, [1.0], good),            # velocity where the layout has none
                 (0, 0, 3.0, None, good),              # a scalar is no array of 2
                 (2**31, 0, good, None, good),         # sec beyond int32
                 (0, 2**32, good, None, good),         # nanosec beyond uint32
                 (0, -1, good, None, good)):
        with pytest.raises((ValueError, TypeError)):
            enc.encode(*args)
    with pytest.raises(ValueError):
        JointStateEncoder(["a"], (1, -1, 1))


def test_decode_block_splits_runs_by_layout():
    names = ["joint_a1", "joint_a2", "joint_a3"]
    msgs = [_msg(names, [k, k + 1, k + 2], [k] * 3, [-k] * 3, sec=k, nanosec=10 * k) for k in range(6)]
    msgs.insert(3, _msg(names, [9.0], [], [], sec=99))            # a short one in the middle
    payloads = [serialize_message(m) for m in msgs]
    dec = JointStateDecoder()
    runs = dec.decode_block(payloads)
    assert [len(sec) for sec, _, _ in runs] == [3, 1, 3]
    flat = []
    for sec, nsec, js in runs:
        for i in range(len(sec)):
            flat.append((int(stamp_ns(sec[i], nsec[i])), js.name, js.position[i], js.velocity[i],
                         js.effort[i]))
    assert len(flat) == len(msgs)
    for (ns, name, p, v, e), m in zip(flat, msgs):
        assert ns == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        assert list(name) == list(m.name)
        for got, want in ((p, m.position), (v, m.velocity), (e, m.effort)):
            assert np.array_equal(got, np.array(want, dtype=np.float64))
    assert runs[0][2].sec == 0 and runs[2][2].sec == 3
    assert dec.parsed == 2 and dec.fast == 5     # the first layout remembered for the last run
    with pytest.raises(ValueError):
        dec.decode_block(payloads[:2] + [payloads[2][:20]])
