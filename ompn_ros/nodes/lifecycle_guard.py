"""Lifecycle requests that make no sense in the node's state: refused, never fatal.

rclpy 7.1.6 handles a ``~/change_state`` request by asking the state machine for the transition and
lets rcl's error escape when the transition does not start at the current state (``activate`` while
active, ``activate`` after a failed configure): the executor re-raises it and the node process dies
(ros2/rclpy#1209, fixed upstream in ros2/rclpy#1319).  :func:`guard_change_state` wraps the service's
callback: a request for a transition the current state does not offer gets the standard refusal
(``success: false``) and one log line naming the state and the transitions it allows; a valid one runs
as before.  No cost outside lifecycle requests.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["guard_change_state", "refusal", "transition_offered"]


def transition_offered(available: list[tuple[Any, ...]], transition_id: int, label: str) -> bool:
    """True when the transition (by ``label`` when given, else by ``transition_id``, rclpy's rule)
    starts at the current state; ``available`` = the state machine's ``available_transitions``
    (``(id, label, start_id, start_label, goal_id, goal_label)`` rows)."""
    if label:
        return any(row[1] == label for row in available)
    return any(int(row[0]) == int(transition_id) for row in available)


def refusal(state: str, transition_id: int, label: str, available: list[tuple[Any, ...]],
            graph: tuple[tuple[Any, ...], ...] | list[tuple[Any, ...]] = ()) -> str:
    """The one line of a refused request: the request (its label, looked up in the transition
    ``graph`` for a request by id), the state and the transitions the state allows."""
    named = {int(row[0]): str(row[1]) for row in graph}
    wanted = label or named.get(int(transition_id), f"transition id {transition_id}")
    allowed = ", ".join(sorted({str(row[1]) for row in available})) or "none"
    return f"lifecycle request '{wanted}' refused: the node is '{state}', which allows only: {allowed}"


def guard_change_state(node: Any, log: Callable[[str], None]) -> None:
    """Wrap ``node``'s ``~/change_state`` service so that invalid requests are refused with ``log``
    (one line) instead of raising; a no-op when the node has no lifecycle services."""
    service = getattr(node, "_service_change_state", None)
    if service is None:
        return
    inner = service.callback
    machine = node._state_machine

    def guarded(request: Any, response: Any) -> Any:
        transition = request.transition
        available = list(machine.available_transitions)
        if transition_offered(available, transition.id, transition.label):
            return inner(request, response)
        state, graph = str(machine.current_state[1]), list(machine.transition_graph)
        log(refusal(state, transition.id, transition.label, available, graph))
        response.success = False
        return response

    service.callback = guarded
