"""smoke_talker when SIGINT shuts its context down (rclpy's signal handler) before it waits for acks."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

rclpy = pytest.importorskip("rclpy")

from ompn_ros.nodes.dds_probe import SmokeTalker  # noqa: E402


@pytest.fixture
def talker() -> Iterator[SmokeTalker]:
    rclpy.init(args=["smoke_talker", "--ros-args", "-p", "count:=3", "-p", "rate:=100.0",
                     "-p", "wait_for_subscriber:=0.0", "-r", "smoke:=/smoke_shutdown_test"])
    node = SmokeTalker()
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def _summary(capsys: pytest.CaptureFixture[str]) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_a_context_shut_down_before_publishing_ends_the_run_with_its_summary(
    talker: SmokeTalker, capsys: pytest.CaptureFixture[str]
) -> None:
    rclpy.shutdown()  # what the SIGINT handler does
    talker.run()  # no RCLError from waiting on a publisher of a dead context
    assert _summary(capsys) == {"published": 0, "matched": 0, "acked": False, "topic": "/smoke_shutdown_test"}


def test_a_context_shut_down_while_waiting_for_acks_ends_the_run_with_its_summary(
    talker: SmokeTalker, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    wait = talker.publisher.wait_for_all_acked

    def shut_down_then_wait(timeout):  # type: ignore[no-untyped-def]
        rclpy.shutdown()
        return wait(timeout)

    monkeypatch.setattr(talker.publisher, "wait_for_all_acked", shut_down_then_wait)
    talker.run()
    summary = _summary(capsys)
    assert summary["published"] == 3 and summary["acked"] is False
