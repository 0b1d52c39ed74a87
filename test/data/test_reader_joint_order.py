"""Joint order is a contract (``ompn_ros.data.reader.joints.first_names_order``): without
``joint_names`` the first message's names fix the order, a message naming the same joints in another
order is reordered, other joints are refused in one line naming those that appear or vanish."""

from __future__ import annotations

from pathlib import Path

import pytest
from compat_corpus import ARM, ARM_JOINTS, ARM_SPEC, arm_demos, check_arm, write_arm

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.cache import load_arrays
from ompn_ros.data.errors import JointNamesError

LENGTHS = [20, 25, 18]
SHUFFLED = ("wrist", "shoulder", "elbow")


def test_names_in_another_order_per_message(tmp_path: Path) -> None:
    """Every other message names the joints in another order (was: 57 of 66 rows scrambled)."""
    demo = arm_demos(LENGTHS, names=lambda k: SHUFFLED if k % 2 else ARM_JOINTS)
    check_arm(read_episodes(write_arm(tmp_path / "bag", demo), spec=ARM_SPEC).episodes, demo)


def test_driver_restart_changes_the_order(tmp_path: Path) -> None:
    """A driver restarted mid-bag lists the joints in another order from then on."""
    demo = arm_demos(LENGTHS, names=lambda k: ARM_JOINTS if k < 30 else SHUFFLED)
    check_arm(read_episodes(write_arm(tmp_path / "bag", demo), spec=ARM_SPEC).episodes, demo)


def test_two_recordings_in_two_orders(tmp_path: Path) -> None:
    """Two bags whose drivers list the joints in two orders, read together and into the cache: the
    first bag's order holds for both (was: every row of the second recording scrambled)."""
    first = arm_demos([20], seed=1)
    second = arm_demos([25, 18], seed=2, names=lambda k: SHUFFLED)
    write_arm(tmp_path / "bags" / "a", first)
    write_arm(tmp_path / "bags" / "b", second)
    both = type(first)(first.observations + second.observations, first.actions + second.actions,
                       labels=first.labels + second.labels)
    check_arm(read_episodes(tmp_path / "bags", spec=ARM_SPEC).episodes, both)
    arrays = load_arrays(tmp_path / "bags", spec=ARM_SPEC, cache_dir=tmp_path / "cache")
    for ep, obs in zip(arrays.episodes(), both.observations):
        assert (ep.observations == obs).all()


@pytest.mark.parametrize("case", ["appear", "vanish", "other urdf"])
@pytest.mark.parametrize("on_error", ["raise", "skip_tail"])
def test_other_joints_are_refused(tmp_path: Path, case: str, on_error: str) -> None:
    """A joint appears or vanishes mid-bag, or a second bag comes from another URDF: refused in one
    line naming the joints and ``joint_names``, whatever ``on_error`` (was: 'observation holds NaN or
    infinite values', or under ``skip_tail`` 2 of 3 good episodes dropped)."""
    other = {"appear": ("shoulder", "elbow", "wrist", "gripper"), "vanish": ("shoulder", "elbow"),
             "other urdf": ("shoulder", "elbow", "wrist_roll")}[case]
    if case == "other urdf":
        write_arm(tmp_path / "bags" / "a", arm_demos([20], seed=1))
        bag = tmp_path / "bags"
        write_arm(bag / "b", arm_demos([25], seed=2, names=lambda k: other), storage="mcap")
    else:
        bag = write_arm(tmp_path / "bag", arm_demos(LENGTHS, names=lambda k: ARM_JOINTS if k < 30 else other))
    with pytest.raises(JointNamesError) as info:
        read_episodes(bag, spec=ARM_SPEC, on_error=on_error)  # type: ignore[arg-type]
    text = str(info.value)
    assert f"'{ARM}'" in text and "joint_names" in text and "NaN" not in text and "\n" not in text
    if case == "appear":
        assert "joints ['gripper'] appear" in text and "message #30" in text
    elif case == "vanish":
        assert "joints ['wrist'] vanish" in text and "message #30" in text
    else:
        assert "joints ['wrist_roll'] appear; joints ['wrist'] vanish" in text and "earlier bag" in text


def test_joint_names_reads_the_named_joints(tmp_path: Path) -> None:
    """The way out the refusal names: ``joint_names`` reads those joints from every message."""
    demo = arm_demos(LENGTHS, names=lambda k: ARM_JOINTS if k < 30 else (*SHUFFLED, "gripper"))
    spec = ReaderSpec.from_dict({**ARM_SPEC.to_dict(), "observation": {
        **ARM_SPEC.to_dict()["observation"], "joint_names": list(ARM_JOINTS)}})
    check_arm(read_episodes(write_arm(tmp_path / "bag", demo), spec=spec).episodes, demo)
