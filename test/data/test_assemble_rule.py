"""The assembly rule on hand-made streams: latest partner at or before the step, tolerance, drops
counted by reason, late partners, bad bytes, wrong sizes and types; the extractors against rosbags."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from ompn_ros.data import messages as m
from ompn_ros.data.obs import Drop, ObservationAssembler, ObservationSpec, TopicExtractor, assemble_stream

MS = 1_000_000
C = m.msg_class


def js(stamp: int, names=("j1", "j2", "j3"), pos=(1.0, 2.0, 3.0), vel=()) -> bytes:
    return m.serialize(m.joint_state(stamp, list(names), pos, vel))


def grip(*values: float) -> bytes:
    return m.encode_float32_array(values, "gripper")


def wrench(stamp: int, force=(1.0, 2.0, 3.0), torque=(4.0, 5.0, 6.0), frame: str = "ft") -> bytes:
    v3 = C("geometry_msgs/msg/Vector3")
    w = C("geometry_msgs/msg/Wrench")(force=v3(*force), torque=v3(*torque))
    return m.serialize(C("geometry_msgs/msg/WrenchStamped")(header=m.header(stamp, frame), wrench=w))


def pose(stamp: int, p=(1.0, 2.0, 3.0), q=(0.0, 0.0, 0.6, 0.8), frame: str = "") -> bytes:
    pt, qt = C("geometry_msgs/msg/Point")(*p), C("geometry_msgs/msg/Quaternion")(*q)
    msg = C("geometry_msgs/msg/Pose")(position=pt, orientation=qt)
    return m.serialize(C("geometry_msgs/msg/PoseStamped")(header=m.header(stamp, frame), pose=msg))


def f64_array(values, labels: int = 1) -> bytes:
    dims = [C("std_msgs/msg/MultiArrayDimension")(label="x" * k, size=len(values), stride=len(values))
            for k in range(labels)]
    lay = C("std_msgs/msg/MultiArrayLayout")(dim=dims, data_offset=0)
    return m.serialize(C("std_msgs/msg/Float64MultiArray")(layout=lay, data=np.asarray(values, float)))


SPEC = ObservationSpec.from_dict({
    "step_topic": "/arm/js",
    "tolerance_s": 0.010,
    "fields": [
        {"topic": "/arm/js", "type": "JointState", "field": "position", "names": ["j3", "j1"]},
        {"topic": "/arm/grip", "type": "Float32MultiArray", "field": "data", "size": 2},
        {"topic": "/arm/ft", "type": "WrenchStamped", "field": "force"},
    ],
})


def expected(pos=(3.0, 1.0), g=(0.0, 0.0), f=(1.0, 2.0, 3.0)) -> np.ndarray:
    return np.asarray([*pos, *g, *f], dtype=np.float32)


def test_latest_at_or_before_and_names() -> None:
    asm = ObservationAssembler(SPEC)
    for t in (10, 20, 30):
        assert asm.offer("/arm/grip", t * MS, grip(t, -t)) is None
        assert asm.offer("/arm/ft", 0, wrench(t * MS, force=(t, 0, 0))) is None  # header stamp rules
    out = asm.step(25 * MS, js(25 * MS))
    np.testing.assert_array_equal(out, expected(g=(20, -20), f=(20, 0, 0)))
    out = asm.step(30 * MS, js(30 * MS))  # equal stamps count as "at or before"
    np.testing.assert_array_equal(out, expected(g=(30, -30), f=(30, 0, 0)))
    assert asm.dim == 7 and asm.obs_names()[:3] == ("arm/js/position/j3", "arm/js/position/j1",
                                                     "arm/grip/data/0")
    assert asm.stats.steps == 2 and asm.stats.kept == 2 and not asm.stats.dropped


def test_tolerance_missing_and_stale_are_counted() -> None:
    asm = ObservationAssembler(SPEC)
    drop = asm.step(5 * MS, js(5 * MS))
    assert isinstance(drop, Drop) and drop.reason == "missing" and drop.topic == "/arm/grip"
    asm.offer("/arm/grip", 10 * MS, grip(1, 2))
    asm.offer("/arm/ft", 0, wrench(10 * MS))
    assert not isinstance(asm.step(20 * MS, js(20 * MS)), Drop)  # exactly the tolerance: kept
    drop = asm.step(20 * MS + 1, js(20 * MS + 1))
    assert isinstance(drop, Drop) and drop.reason == "stale" and "tolerance 10 ms" in drop.detail
    drop = asm.step(9 * MS, js(9 * MS))  # partners only after the step: missing
    assert isinstance(drop, Drop) and drop.reason == "missing" and "at or before" in drop.detail
    assert asm.stats.dropped == {"missing": 2, "stale": 1}
    assert asm.stats.kept + sum(asm.stats.dropped.values()) == asm.stats.steps == 4


def test_partner_arriving_after_its_step_serves_later_steps_only() -> None:
    asm = ObservationAssembler(SPEC)
    asm.offer("/arm/ft", 0, wrench(0))
    asm.offer("/arm/grip", 1 * MS, grip(1, 1))
    # the step of t=5 ms arrives before the gripper message stamped 4 ms: the older one is used
    np.testing.assert_array_equal(asm.step(5 * MS, js(5 * MS)), expected(g=(1, 1)))
    asm.offer("/arm/grip", 4 * MS, grip(4, 4))
    np.testing.assert_array_equal(asm.step(6 * MS, js(6 * MS)), expected(g=(4, 4)))
    asm.offer("/arm/grip", 2 * MS, grip(2, 2))  # out of order: sorted into the history
    np.testing.assert_array_equal(asm.step(3 * MS, js(3 * MS)), expected(g=(2, 2)))


def test_malformed_and_wrong_size_partner_occupy_their_stamp() -> None:
    asm = ObservationAssembler(SPEC)
    asm.offer("/arm/ft", 0, wrench(0))
    asm.offer("/arm/grip", 1 * MS, grip(1, 1))
    bad = asm.offer("/arm/grip", 2 * MS, b"\x00\x01\x00\x00\x05")
    assert isinstance(bad, Drop) and bad.reason == "malformed"
    drop = asm.step(3 * MS, js(3 * MS))
    assert isinstance(drop, Drop) and drop.reason == "malformed" and drop.topic == "/arm/grip"
    bad = asm.offer("/arm/grip", 4 * MS, grip(1, 2, 3))
    assert isinstance(bad, Drop) and bad.reason == "wrong_size" and "3 elements, expected 2" in bad.detail
    drop = asm.step(5 * MS, js(5 * MS))
    assert isinstance(drop, Drop) and drop.reason == "wrong_size"
    asm.offer("/arm/grip", 6 * MS, grip(6, 6))
    np.testing.assert_array_equal(asm.step(7 * MS, js(7 * MS)), expected(g=(6, 6)))
    assert asm.stats.rejected == {("/arm/grip", "malformed"): 1, ("/arm/grip", "wrong_size"): 1}
    assert asm.stats.dropped == {"malformed": 1, "wrong_size": 1}


def test_bad_step_messages() -> None:
    asm = ObservationAssembler(SPEC)
    asm.offer("/arm/ft", 0, wrench(0))
    asm.offer("/arm/grip", 0, grip(0, 0))
    for raw, reason, text in [
        (b"garbage", "malformed", "cannot decode"),
        (js(1, names=("j1", "j2"), pos=(1.0, 2.0)), "malformed", "['j3'] not in the message"),
        (js(1, pos=(1.0, 2.0)), "wrong_size", "2 values for 3 joints"),
    ]:
        drop = asm.step(1, raw)
        assert isinstance(drop, Drop) and drop.topic == "/arm/js" and drop.reason == reason
        assert text in drop.detail
    np.testing.assert_array_equal(asm.step(1, js(1, names=("j3", "j2", "j1"), pos=(30, 20, 10))),
                                  expected(pos=(30, 10)))


def test_wrong_type_reported_once_per_check_and_counted() -> None:
    asm = ObservationAssembler(SPEC)
    problem = asm.check_type("/arm/grip", "std_msgs/msg/Float64MultiArray")
    assert problem == ("topic '/arm/grip' has type std_msgs/msg/Float64MultiArray, the observation spec "
                       "expects std_msgs/msg/Float32MultiArray")
    assert asm.check_type("/arm/grip", "std_msgs/msg/Float64MultiArray") == problem  # polled: counted once
    assert asm.check_type("/arm/ft", "geometry_msgs/WrenchStamped") is None
    assert asm.check_type("/elsewhere", "std_msgs/msg/String") is None
    asm.offer("/arm/ft", 0, wrench(0))
    rejected = asm.offer("/arm/grip", 0, f64_array([1.0, 2.0]))
    assert isinstance(rejected, Drop) and rejected.reason == "wrong_type"
    drop = asm.step(0, js(0))
    assert isinstance(drop, Drop) and drop.reason == "wrong_type" and drop.topic == "/arm/grip"
    assert asm.stats.rejected[("/arm/grip", "wrong_type")] == 2
    assert asm.check_type("/arm/grip", "std_msgs/msg/Float32MultiArray") is None
    asm.offer("/arm/grip", 0, grip(5, 5))
    np.testing.assert_array_equal(asm.step(0, js(0)), expected(g=(5, 5)))


def test_stamp_rule_header_receive_and_zero_header() -> None:
    receive = ObservationSpec.from_dict({**SPEC.to_dict(), "stamp": "receive"})
    for spec, kept in ((SPEC, True), (receive, False)):
        asm = ObservationAssembler(spec)
        asm.offer("/arm/grip", 50 * MS, grip(0, 0))
        asm.offer("/arm/ft", 100 * MS, wrench(50 * MS))  # header 50 ms, received at 100 ms
        out = asm.step(60 * MS, js(55 * MS))  # header 55 ms, received at 60 (receive rule: before ft)
        assert isinstance(out, np.ndarray) is kept
        assert asm.last_stamp_ns == (55 * MS if kept else 60 * MS)
    # each partner on its own clock: the gripper (no header) against the step's reception, so a
    # backlog of the receiver that delays the step and the gripper alike does not age the gripper
    asm = ObservationAssembler(SPEC)
    asm.offer("/arm/ft", 300 * MS, wrench(50 * MS))
    asm.offer("/arm/grip", 300 * MS, grip(7, 7))  # published with the step below, received 250 ms late
    np.testing.assert_array_equal(asm.step(301 * MS, js(51 * MS)), expected(g=(7, 7)))
    asm = ObservationAssembler(SPEC)  # a zero header stamp (unset by the driver) falls back to receive
    asm.offer("/arm/grip", 10 * MS, grip(0, 0))
    asm.offer("/arm/ft", 10 * MS, wrench(0))
    assert isinstance(asm.step(12 * MS, js(0)), np.ndarray) and asm.last_stamp_ns == 12 * MS


def test_a_stalled_receiver_does_not_age_reception_stamped_partners() -> None:
    """Steps 1 ms apart, received 0.1 ms after their header stamp, a gripper every 4th step; then
    the receiver stalls 200 ms and serves the next step before the grippers queued behind it."""
    stalled = ObservationAssembler(SPEC)  # tolerance 10 ms
    for k in range(8):
        t = k * MS
        if k % 4 == 0:
            stalled.offer("/arm/grip", t + 50_000, grip(k, k))
        stalled.offer("/arm/ft", t + 60_000, wrench(t))
        assert isinstance(stalled.step(t + 100_000, js(t)), np.ndarray)
    stalled.offer("/arm/ft", 208 * MS, wrench(8 * MS))
    out = stalled.step(208 * MS, js(8 * MS))  # received 200 ms late, its gripper not served yet
    np.testing.assert_array_equal(out, expected(g=(4, 4)))  # the gripper of step 4: 4 ms older
    stalled.offer("/arm/grip", 208 * MS + 1, grip(8, 8))  # the backlog: stamped after the step
    stalled.offer("/arm/ft", 208 * MS + 2, wrench(9 * MS))
    np.testing.assert_array_equal(stalled.step(208 * MS + 3, js(9 * MS)), expected(g=(8, 8)))
    # a gripper that really went silent is still stale: on-time steps more than 10 ms after it
    for k in range(210, 222):
        stalled.offer("/arm/ft", k * MS + 60_000, wrench(k * MS))
        out = stalled.step(k * MS + 100_000, js(k * MS))
    assert isinstance(out, Drop) and out.reason == "stale" and out.topic == "/arm/grip"
    assert "13.100 ms older" in out.detail and stalled.stats.dropped == {"stale": 4}  # 218..221


def test_reset_forgets_partners_and_keeps_counters() -> None:
    asm = ObservationAssembler(SPEC)
    asm.offer("/arm/grip", 0, grip(0, 0))
    asm.offer("/arm/ft", 0, wrench(1))
    assert isinstance(asm.step(2, js(2)), np.ndarray)
    asm.reset()
    drop = asm.step(3, js(3))
    assert isinstance(drop, Drop) and drop.reason == "missing" and drop.detail == "no message yet"
    assert asm.stats.steps == 2
    asm.reset(clear_stats=True)
    assert asm.stats.steps == 0 and asm.dim == 7
    assert asm.offer("/unused", 0, b"") is None and asm.stats.ignored == 1
    with pytest.raises(ValueError, match="step topic"):
        asm.offer("/arm/js", 0, js(0))


def test_joint_order_pinned_by_first_message() -> None:
    spec = ObservationSpec.from_dict({"step_topic": "/js", "fields": [
        {"topic": "/js", "type": "JointState", "field": "position"},
        {"topic": "/js", "type": "JointState", "field": "velocity"}]})
    asm = ObservationAssembler(spec)
    out = asm.step(0, js(1, ("a", "b", "c"), (1, 2, 3), (4, 5, 6)))
    np.testing.assert_array_equal(out, [1, 2, 3, 4, 5, 6])
    out = asm.step(0, js(2, ("c", "a", "b"), (3, 1, 2), (6, 4, 5)))
    np.testing.assert_array_equal(out, [1, 2, 3, 4, 5, 6])
    assert asm.obs_names()[3] == "js/velocity/a"
    drop = asm.step(0, js(3, ("a", "b", "c"), (1, 2, 3), ()))  # empty velocity
    assert isinstance(drop, Drop) and drop.reason == "wrong_size"


@pytest.mark.parametrize("little_endian", [True, False])
@pytest.mark.parametrize("frame", ["", "f", "ft_sensor", "frame_id_9"])
def test_extractors_match_rosbags(little_endian: bool, frame: str) -> None:
    ts = m.typestore()

    def recode(raw: bytes, typename: str) -> bytes:
        return raw if little_endian else bytes(ts.serialize_cdr(m.deserialize(raw, typename), typename,
                                                                little_endian=False))

    wrench_t, pose_t, f64a_t = ("geometry_msgs/msg/WrenchStamped", "geometry_msgs/msg/PoseStamped",
                                "std_msgs/msg/Float64MultiArray")
    cases = [
        (wrench_t, "wrench", wrench(7, (1, 2, 3), (4, 5, 6), frame), [1, 2, 3, 4, 5, 6]),
        (wrench_t, "torque", wrench(7, frame=frame), [4, 5, 6]),
        (pose_t, "pose", pose(7, frame=frame), [1, 2, 3, 0, 0, 0.6, 0.8]),
        (pose_t, "orientation", pose(7, frame=frame), [0, 0, 0.6, 0.8]),
        (f64a_t, "data", f64_array([1.5, -2.5, 3.25], len(frame)), [1.5, -2.5, 3.25]),
        ("std_msgs/msg/Float32MultiArray", "data", m.encode_float32_array([0.5, 2], frame or "x"), [0.5, 2]),
        ("std_msgs/msg/Float64", "data", m.serialize(C("std_msgs/msg/Float64")(data=-1.25)), [-1.25]),
        ("std_msgs/msg/Float32", "data", m.serialize(C("std_msgs/msg/Float32")(data=0.75)), [0.75]),
        ("sensor_msgs/msg/JointState", "effort",
         m.serialize(m.joint_state(7, ["a", "b"], [1, 2], [], [3, 4])), [3, 4]),
    ]
    for typename, field, raw, want in cases:
        spec = ObservationSpec.from_dict({"step_topic": "/t", "fields": [
            {"topic": "/t", "type": typename, "field": field}]})
        stamp, (vec,) = TopicExtractor("/t", spec.fields).extract(recode(raw, typename))
        np.testing.assert_allclose(vec, want, err_msg=f"{typename}.{field}")
        assert stamp == (7 if typename.split("/")[0] in ("geometry_msgs", "sensor_msgs") else None)


def test_assemble_stream_is_the_assembler_in_record_order() -> None:
    rng = np.random.default_rng(0)
    msgs: list[tuple[str, int, bytes]] = []
    for k in range(200):
        t = k * MS
        if rng.random() < 0.9:
            msgs.append(("/arm/grip", t + 100, grip(*rng.normal(size=2))))
        if rng.random() < 0.9:
            msgs.append(("/arm/ft", t + 200, wrench(t + 150, force=tuple(rng.normal(size=3)))))
        if rng.random() < 0.05:
            msgs.append(("/arm/ft", t + 250, b"\x00\x01\x00\x00junk"))
        msgs.append(("/other", t + 300, b""))
        msgs.append(("/arm/js", t + 400, js(t + 350, pos=tuple(rng.normal(size=3)))))
    res = assemble_stream(msgs, SPEC)
    asm = ObservationAssembler(SPEC)
    manual = [asm.step(s, r) if tp == "/arm/js" else asm.offer(tp, s, r) for tp, s, r in msgs]
    steps = [x for (tp, _, _), x in zip(msgs, manual) if tp == "/arm/js"]
    kept = [x for x in steps if isinstance(x, np.ndarray)]
    assert res.kept.tolist() == [isinstance(x, np.ndarray) for x in steps]
    np.testing.assert_array_equal(res.observations, np.stack(kept))
    assert len(res.drops) == len(steps) - len(kept) > 0
    # every wrench is stamped after the step before it: held steps decide as at once, but the last
    # step waits for a wrench that never comes and is flushed at the end, late
    assert res.stats.as_dict() == {**asm.stats.as_dict(), "late": 1}
    assert res.stats.ignored == 200 and res.observations.shape[1] == 7 and len(res.names) == 7
    js_log = np.asarray([s for tp, s, _ in msgs if tp == "/arm/js"])[res.kept]
    np.testing.assert_array_equal(res.log_stamps, js_log)
    np.testing.assert_array_equal(res.step_log_stamps[res.kept], js_log)
    assert len(res.step_log_stamps) == len(steps)
    np.testing.assert_array_equal(res.stamps, js_log - 50)  # header stamps
    wrong = assemble_stream(msgs[:10], SPEC, types={"/arm/ft": "geometry_msgs/msg/PoseStamped"})
    assert wrong.type_problems and wrong.observations.shape == (0, 7)
    assert {d.reason for d in wrong.drops} == {"wrong_type"}
    half = ObservationAssembler(SPEC)  # continuing one assembler over two parts = one pass
    first = assemble_stream(msgs[:300], SPEC, assembler=half, flush=False)
    rest = assemble_stream(msgs[300:], SPEC, assembler=half)
    np.testing.assert_array_equal(np.concatenate([first.observations, rest.observations]), res.observations)
    assert half.stats.as_dict() == res.stats.as_dict() and half.held == 0
    with pytest.raises(ValueError, match="another observation spec"):
        assemble_stream(msgs, ObservationSpec.single_topic("/arm/js"), assembler=half)


def test_joint_state_parser_relearns_when_the_layout_changes() -> None:
    from ompn_ros.data.messages import JointStateParser

    parser = JointStateParser()
    rng = np.random.default_rng(1)
    variants = [(("a", "b"), ""), (("a", "b"), ""), (("b", "a"), ""), (("a", "c"), ""), (("a", "b"), "x"),
                (("a", "b", "c"), ""), (("a", "b"), "")]
    for names, frame in variants:
        msg = m.joint_state(int(rng.integers(1, 10**12)), list(names), rng.normal(size=len(names)),
                            rng.normal(size=len(names)) if frame else ())
        msg.header.frame_id = frame
        raw = m.serialize(msg)
        got_stamp, got, got_names = parser.parse(raw)
        want_names, want_stamp, want = m.parse_joint_state(raw)
        assert (got_names, got_stamp) == (tuple(want_names), want_stamp)
        for field in ("position", "velocity", "effort"):
            np.testing.assert_array_equal(got[field], want[field])
        with pytest.raises((ValueError, struct.error)):
            parser.parse(raw[:-3])
    padded = m.serialize(m.joint_state(5, ["a"], [1.0])) + b"\0" * 4  # Fast CDR's trailing padding
    assert parser.parse(padded)[1]["position"].tolist() == [1.0]


def test_partner_offered_from_a_reused_buffer_is_kept_intact() -> None:
    asm = ObservationAssembler(SPEC)
    buffer = bytearray(wrench(1, force=(1.0, 2.0, 3.0)))
    asm.offer("/arm/ft", 0, memoryview(buffer))
    buffer[:] = wrench(1, force=(9.0, 9.0, 9.0))  # a reader reusing its buffer for the next message
    asm.offer("/arm/grip", 0, memoryview(bytearray(grip(1.0, 2.0))))
    np.testing.assert_array_equal(asm.step(2, memoryview(bytearray(js(2)))), expected(g=(1, 2)))


def test_same_field_twice_with_other_joints() -> None:
    spec = ObservationSpec.from_dict({"step_topic": "/js", "fields": [
        {"topic": "/js", "type": "JointState", "field": "position", "names": ["j1"]},
        {"topic": "/g", "type": "Float64", "field": "data"},
        {"topic": "/js", "type": "JointState", "field": "position", "names": ["j3", "j2"]}]})
    asm = ObservationAssembler(spec)
    asm.offer("/g", 0, m.serialize(C("std_msgs/msg/Float64")(data=7.0)))
    np.testing.assert_array_equal(asm.step(0, js(1)), [1, 7, 3, 2])
    assert asm.obs_names() == ("js/position/j1", "g/data/data", "js/position/j3", "js/position/j2")


def _hold_all(asm: ObservationAssembler, msgs: list[tuple[str, int, bytes]]) -> list:
    """Feed ``(topic, receive_ns, raw)`` with the hold; released steps as ``(stamp, result, late)``."""
    out = []
    for topic, now, raw in msgs:
        if topic == "/arm/js":
            asm.hold(now, raw)
        else:
            asm.offer(topic, now, raw)
        out += [(d.stamp_ns, d.result, d.late) for d in asm.release(now)]
    return out


def test_partner_after_its_step_gives_the_in_order_observation() -> None:
    grips = [("/arm/grip", k * MS, grip(k, -k)) for k in range(6)]
    in_order, late_ft = [], []
    for k in range(6):  # wrench k stamped 0.5 ms before step k; delivered before it, or after it
        ft = ("/arm/ft", k * MS + 600_000, wrench(k * MS, force=(k, 0, 0)))
        step = ("/arm/js", 0, js(k * MS + MS // 2))
        in_order += [grips[k], ft, step]
        late_ft += [grips[k], step, ft]
    for msgs in (in_order, late_ft):
        msgs[:] = [(t, now if t != "/arm/js" else i * 1000 + 5 * MS, r) for i, (t, now, r) in enumerate(msgs)]
    # (the gripper is stamped at reception, before its step's header stamp: it is not waited for)
    a, b = ObservationAssembler(SPEC), ObservationAssembler(SPEC)
    got_a, got_b = _hold_all(a, in_order), _hold_all(b, late_ft)
    got_a += [(d.stamp_ns, d.result, d.late) for d in a.release(flush=True)]
    got_b += [(d.stamp_ns, d.result, d.late) for d in b.release(flush=True)]
    assert [s for s, _, _ in got_a] == [s for s, _, _ in got_b] == [k * MS + MS // 2 for k in range(6)]
    for (_, x, _), (_, y, _) in zip(got_a, got_b, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(got_b[3][1][4:], [3, 0, 0])  # wrench 3: fed after step 3, still used
    assert [late for *_, late in got_b] == [False] * 5 + [True]  # the last one never saw a later wrench
    # without waiting, the late wrench is not used: the previous one (2 ms old) serves step 3
    now = ObservationAssembler(ObservationSpec.from_dict({**SPEC.to_dict(), "wait_s": 0}))
    np.testing.assert_array_equal(_hold_all(now, late_ft)[3][1][4:], [2, 0, 0])


def test_a_partner_that_never_comes_releases_after_the_wait() -> None:
    asm = ObservationAssembler(SPEC)  # wait_s 0.1
    asm.offer("/arm/grip", 5 * MS, grip(1, 2))
    asm.offer("/arm/ft", 0, wrench(1 * MS))
    asm.hold(10 * MS, js(2 * MS))
    asm.hold(11 * MS, js(3 * MS))
    assert asm.release(10 * MS + 99 * MS) == [] and asm.held == 2
    first = asm.release(110 * MS)  # the first step's wait is over; the second waits on
    assert [(d.stamp_ns, d.late) for d in first] == [(2 * MS, True)] and asm.held == 1
    np.testing.assert_array_equal(first[0].result, expected(g=(1, 2)))
    asm.offer("/arm/ft", 112 * MS, wrench(3 * MS))  # stamped at the second step: it settles it
    (second,) = asm.release(112 * MS)
    assert not second.late and second.receive_ns == 11 * MS
    assert asm.stats.as_dict() == {"steps": 2, "kept": 2, "late": 1, "ignored": 0}


def test_what_never_waits() -> None:
    receive = ObservationSpec.from_dict({**SPEC.to_dict(), "stamp": "receive"})
    single = ObservationSpec.single_topic("/arm/grip", size=2)
    for spec in (receive, single):  # partners stamped at reception, or no partner at all
        asm = ObservationAssembler(spec)
        asm.hold(5, grip(1, 2) if spec is single else js(5))
        (d,) = asm.release(5)
        assert not d.late and asm.held == 0
    bounded = ObservationAssembler(SPEC, max_held=2)  # the queue is bounded: the oldest goes late
    for k in range(3):
        bounded.hold(k, js(k))
    assert [d.stamp_ns for d in bounded.release(3)] == [0] and bounded.held == 2
    with pytest.raises(ValueError, match="held"):
        bounded.step(4, js(4))
    assert [d.late for d in bounded.reset()] == [True, True] and bounded.stats.late == 3
    assert bounded.stats.dropped == {"missing": 3} and bounded.held == 0


def test_a_rejected_or_wrong_type_partner_does_not_hold_forever() -> None:
    asm = ObservationAssembler(SPEC)
    asm.offer("/arm/grip", 0, grip(1, 2))
    asm.hold(1, js(5 * MS))
    asm.offer("/arm/ft", 2, b"\x00\x01\x00\x00junk")  # its receive stamp: before the step, still waits
    assert asm.release(2) == []
    asm.offer("/arm/ft", 6 * MS, b"\x00\x01\x00\x00junk")  # rejected, stamped after: settles, occupies
    (d,) = asm.release(6 * MS)
    assert isinstance(d.result, Drop) and d.result.reason == "malformed" and not d.late
    asm.check_type("/arm/ft", "geometry_msgs/msg/PoseStamped")
    asm.hold(7 * MS, js(7 * MS))
    (d,) = asm.release(7 * MS)
    assert isinstance(d.result, Drop) and d.result.reason == "wrong_type" and not d.late
