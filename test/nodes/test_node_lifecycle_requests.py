"""ompn_node as a process under lifecycle misuse: every request in every state is answered, an invalid
one is refused with one line, ``~/reset`` answers while inactive, and the shutdown transition ends the
process (exit 0).  The node runs as a subprocess with its default executor (DDS on loopback)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from node_process import NodeProcess, Peer  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from ompn_ros.ros import containment  # noqa: E402

IDS = {"configure": Transition.TRANSITION_CONFIGURE, "cleanup": Transition.TRANSITION_CLEANUP,
       "activate": Transition.TRANSITION_ACTIVATE, "deactivate": Transition.TRANSITION_DEACTIVATE,
       "shutdown": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN}  # fmt: skip


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "life", seed=5,
                             obs_dim=4, action_type="discrete", action_dim=3, n_slots=2, slot_size=8)


class Caller:
    """Calls the subprocess node's services from this process."""

    def __init__(self, peer: Peer, proc: NodeProcess) -> None:
        self.peer, self.node, self.proc = peer, peer.node, proc
        self.clients: dict[str, Any] = {}

    def call(self, srv_type: Any, name: str, request: Any = None, timeout: float = 30.0) -> Any:
        client = self.clients.get(name)
        if client is None:
            service = self.proc.topic(f"ompn_node/{name}")
            client = self.clients[name] = self.node.create_client(srv_type, service)
        assert client.wait_for_service(timeout_sec=timeout), f"no service {name}"
        future = client.call_async(request if request is not None else srv_type.Request())
        self.peer.pump(future.done, timeout, watch=name != "change_state")  # a shutdown ends the process
        return future.result() if future.done() else None

    def transition(self, label: str, by_id: bool = True) -> Any:
        """A ``~/change_state`` request by id (as rclpy's own clients send it; rclpy 7.1.6 dies on an
        invalid one) or by label."""
        wanted = Transition(id=IDS[label]) if by_id else Transition(label=label)
        return self.call(ChangeState, "change_state", ChangeState.Request(transition=wanted))

    def state(self) -> str:
        return str(self.call(GetState, "get_state").current_state.label)


def test_lifecycle_misuse_is_refused_and_shutdown_ends_the_process(ckpt: Path, ros_env: dict[str, str]
                                                                   ) -> None:
    proc = NodeProcess(ros_env, f"checkpoint:={ckpt}", ns=f"/life_{os.getpid()}")
    peer = Peer(proc, name="lifecycle_caller")
    try:
        caller = Caller(peer, proc)
        peer.wait_active(proc)
        assert caller.transition("activate").success is False  # invalid while active: refused
        assert caller.transition("configure", by_id=False).success is False
        assert proc.running() and caller.state() == "active"
        assert caller.transition("deactivate").success is True
        reset = caller.call(Trigger, "reset")  # answered while inactive, with the reason
        assert reset is not None and not reset.success and "inactive" in reset.message
        assert caller.transition("deactivate").success is False
        assert caller.transition("cleanup").success is True
        assert caller.transition("activate").success is False  # unconfigured: nothing to activate
        assert caller.transition("shutdown").success is True
        rc = proc.wait(timeout=20)  # the shutdown transition ends the process
    finally:
        peer.close()
        out = proc.stop()
    assert rc == 0, out
    assert "Traceback" not in out and "FATAL" not in out, out
    refused = [line for line in out.splitlines() if "refused" in line]
    assert len(refused) == 4, out  # one line per invalid request
    assert "'activate' refused: the node is 'active'" in out and "allows only: deactivate, shutdown" in out
    for logged in ("activated", "deactivated", "cleaned up", "shut down from 'unconfigured'"):
        assert logged in out, out
    assert not containment.problems()
