"""The cuts of a stream (ROS-free): import them as ``ompn_ros.data.cuts``.

Each rule keeps its batch form (over a bag's arrays: the reader, training) and its live form (one
step at a time: the stream rule of ``ompn_node`` and the replay) in one module, so the two cannot
drift apart (docs/design.md#cuts-of-a-stream).  One word, one meaning: a step is *idle* when the
robot does not move by the idle rule's speed test (``idle_speed``), an observation is *still* when the
model is not stepped on it (``still_tolerance``).

* :mod:`.gap`: a pause between two steps ends an episode (the reader's ``split: gaps``, the node's
  ``episode_gap``; :class:`SilenceWatch` for a pause on the receiver's clock).
* :mod:`.idle`: a robot idle for ``idle_s`` ends an episode (``split: idle``, the node's ``idle_s``;
  ``idle_speed: auto`` from the stream's noise floor).
* :mod:`.still`: the model is stepped only on observations that moved (``still_tolerance``, ``auto``
  from the training episodes); the one applier and the one step-to-row mapper.
* :mod:`.repeats`: a message a driver sent twice is one message.

The names load on first use (:mod:`ompn_ros.lazy`): importing the face for one rule loads no other.
"""

from typing import TYPE_CHECKING

from ompn_ros.lazy import lazy_names

if TYPE_CHECKING:  # the names below load on first use (PEP 562)
    from .gap import GAP_TIMER_FRACTION, SilenceWatch, apart, gap_ends_episode, gap_windows
    from .idle import (
        ALL_ELEMENTS,
        EXACT_SPEED,
        Cut,
        IdleGate,
        IdleSpeed,
        IdleSplitter,
        SpeedElements,
        derive_idle_speed,
        idle_by_speed,
        idle_windows,
        speeds,
        step_idle,
    )
    from .repeats import REPEAT_NS, Repeats, has_header, unrepeated
    from .still import (
        AUTO,
        StillChoice,
        StillRuns,
        check_setting,
        check_tolerance,
        choose_tolerance,
        drop_still,
        element_noise,
        noise_floor,
        noise_margin,
        run_ends,
        still_runs,
    )

_LAZY = {
    "GAP_TIMER_FRACTION": "ompn_ros.data.cuts.gap",
    "SilenceWatch": "ompn_ros.data.cuts.gap",
    "apart": "ompn_ros.data.cuts.gap",
    "gap_ends_episode": "ompn_ros.data.cuts.gap",
    "gap_windows": "ompn_ros.data.cuts.gap",
    "ALL_ELEMENTS": "ompn_ros.data.cuts.idle",
    "EXACT_SPEED": "ompn_ros.data.cuts.idle",
    "Cut": "ompn_ros.data.cuts.idle",
    "IdleGate": "ompn_ros.data.cuts.idle",
    "IdleSpeed": "ompn_ros.data.cuts.idle",
    "IdleSplitter": "ompn_ros.data.cuts.idle",
    "SpeedElements": "ompn_ros.data.cuts.idle",
    "derive_idle_speed": "ompn_ros.data.cuts.idle",
    "idle_by_speed": "ompn_ros.data.cuts.idle",
    "idle_windows": "ompn_ros.data.cuts.idle",
    "speeds": "ompn_ros.data.cuts.idle",
    "step_idle": "ompn_ros.data.cuts.idle",
    "REPEAT_NS": "ompn_ros.data.cuts.repeats",
    "Repeats": "ompn_ros.data.cuts.repeats",
    "has_header": "ompn_ros.data.cuts.repeats",
    "unrepeated": "ompn_ros.data.cuts.repeats",
    "AUTO": "ompn_ros.data.cuts.still",
    "StillChoice": "ompn_ros.data.cuts.still",
    "StillRuns": "ompn_ros.data.cuts.still",
    "check_setting": "ompn_ros.data.cuts.still",
    "check_tolerance": "ompn_ros.data.cuts.still",
    "choose_tolerance": "ompn_ros.data.cuts.still",
    "drop_still": "ompn_ros.data.cuts.still",
    "element_noise": "ompn_ros.data.cuts.still",
    "noise_floor": "ompn_ros.data.cuts.still",
    "noise_margin": "ompn_ros.data.cuts.still",
    "run_ends": "ompn_ros.data.cuts.still",
    "still_runs": "ompn_ros.data.cuts.still",
}

__all__ = [
    "ALL_ELEMENTS",
    "AUTO",
    "EXACT_SPEED",
    "GAP_TIMER_FRACTION",
    "REPEAT_NS",
    "Cut",
    "IdleGate",
    "IdleSpeed",
    "IdleSplitter",
    "Repeats",
    "SilenceWatch",
    "SpeedElements",
    "StillChoice",
    "StillRuns",
    "apart",
    "check_setting",
    "check_tolerance",
    "choose_tolerance",
    "derive_idle_speed",
    "drop_still",
    "element_noise",
    "gap_ends_episode",
    "gap_windows",
    "has_header",
    "idle_by_speed",
    "idle_windows",
    "noise_floor",
    "noise_margin",
    "run_ends",
    "speeds",
    "step_idle",
    "still_runs",
    "unrepeated",
]


__getattr__ = lazy_names(__name__, globals(), _LAZY)
