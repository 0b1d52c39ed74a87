"""The idle gate (``idle_s``) holds a long pause at O(1) work per observation, and steps all of it.

A driver publishing at 500 Hz while the robot waits 25 s before moving on (``idle_s`` 30) leaves
12 500 still observations held.  The gate used to rebuild its set and dict of held steps on every
observation, so each one cost in proportion to the pause so far (5.4 ms at 20 000 held): the node
fell behind its input queue and observations vanished.  Work per observation is measured here by
the memory one push allocates (deterministic, unlike a timing); the time per observation from 0 to
100 000 held steps is ``bench/bench_idle.py``.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from ompn_ros.data.cuts import IdleGate, IdleSplitter

MS = 1_000_000
RATE_NS = 2 * MS  # 500 Hz


def _moving(k: int) -> np.ndarray:
    return np.full(6, 0.1 * k, dtype=np.float32)


def _hold(gate: IdleGate, held: int) -> tuple[int, np.ndarray]:
    """Start an episode with 3 moving steps, then hold ``held`` still observations; the last stamp and
    observation."""
    stamp = 0
    for k in range(3):
        stamp += RATE_NS
        gate.push(_moving(k), stamp)
    still = _moving(2)
    for _ in range(held):
        stamp += RATE_NS
        assert gate.push(still, stamp) == []
    return stamp, still


def _push_peak(gate: IdleGate, obs: np.ndarray, stamp: int) -> int:
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        gate.push(obs, stamp)
        return tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("held", [20_000])
def test_one_still_observation_allocates_the_same_whatever_the_pause(held: int) -> None:
    gate = IdleGate(1_000_000 * MS, idle_speed=0.01)  # idle_s far beyond the pause
    stamp, still = _hold(gate, 10)
    short = _push_peak(gate, still, stamp + RATE_NS)
    gate = IdleGate(1_000_000 * MS, idle_speed=0.01)
    stamp, still = _hold(gate, held)
    long = _push_peak(gate, still, stamp + RATE_NS)
    assert len(gate.splitter.held_rows) == held + 1
    # a set and a dict of 20 000 held rows is over a megabyte; one observation's bookkeeping is not
    assert long < 16 * 1024, f"one push with {held} held allocated {long} bytes (with 10 held: {short})"


def test_a_25_s_pause_at_500_hz_with_idle_30_s_steps_every_observation() -> None:
    """Nothing held is lost: the pause is shorter than idle_s, so every still observation becomes a step
    of the episode when the robot moves again, in order, with its own stamp."""
    gate = IdleGate(30_000 * MS, idle_speed=0.01)
    stamp, _ = _hold(gate, 12_500)  # 25 s at 500 Hz
    decided = gate.push(_moving(10), stamp + RATE_NS)
    kinds = [kind for kind, _, _ in decided]
    assert kinds == ["step"] * 12_501
    stamps = [s for _, _, s in decided]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    assert all(x is not None for _, x, _ in decided)
    assert gate.trimmed == 1 and len(gate.splitter.held_rows) == 0  # the stream's first observation: still
    assert not gate._pending  # nothing of the pause is kept once it is decided


def test_a_pause_longer_than_idle_s_ends_at_its_first_still_step_and_forgets_the_rest() -> None:
    gate = IdleGate(100 * MS, idle_speed=0.01)
    stamp, still = _hold(gate, 50)  # held from 8 to 106 ms: not yet
    decided = gate.push(still, stamp + RATE_NS)  # 100 ms after the first: the episode ends
    assert [kind for kind, _, _ in decided] == ["end"]
    assert decided[0][2] == 4 * RATE_NS  # the first still observation is the final one
    assert gate.trimmed == 1 + 50 and not gate._pending
    assert IdleSplitter(5).held == 0  # the count, O(1)
