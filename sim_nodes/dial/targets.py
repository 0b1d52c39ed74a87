"""Joint-space waypoints of the Dial task, derived by IK on the compiled scene (docs/dial.md §5.6).

The original stored hand-picked joint angles (``targ_def.p``, docs/dial.md §1.8); they do not transfer
to dm_control's arm, so every waypoint is re-derived with :func:`sim_nodes.dial.ik.solve_ik`,
chained from one home posture so all solutions share an IK branch:

* ``home``: reference site at :data:`~sim_nodes.dial.scene.HOME_XYZ`, hand vertical;
* ``approach[d]`` / ``press[d]``: the key's approach / press sites;
* ``retract[d]``: :data:`RETRACT_HEIGHT` above the press point (the explicit lift between digits
  that replaces the original's shoulder "kick", docs/dial.md §3.3).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import mujoco
import numpy as np

from sim_nodes.dial.ik import solve_ik
from sim_nodes.dial.scene import HOME_XYZ, N_KEYS, DialModel, approach_point, press_point, shared_model

FINGER_ANGLE = 1.0  # rad; fingers are held half-closed as a rigid pointer (range 0.15..1.35)
RETRACT_HEIGHT = 0.07  # metres above the press point
# A seed posture on the elbow-up branch that reaches the pad with the hand vertical.
HOME_SEED = np.array([0.41, 1.92, 3.93, 2.77, 1.32, -0.59, FINGER_ANGLE, FINGER_ANGLE, FINGER_ANGLE])


@dataclass(frozen=True)
class Targets:
    """Joint-angle waypoints ([9] each, arm + fingers) and their Cartesian points."""

    home: np.ndarray
    approach: np.ndarray  # [10, 9]
    press: np.ndarray  # [10, 9]
    retract: np.ndarray  # [10, 9]
    approach_xyz: np.ndarray  # [10, 3]
    press_xyz: np.ndarray  # [10, 3]
    retract_xyz: np.ndarray  # [10, 3]


def compute_targets(dm: DialModel) -> Targets:
    """Solve all waypoints (about 0.2 s)."""
    data = mujoco.MjData(dm.model)
    home = solve_ik(dm, np.array(HOME_XYZ), HOME_SEED, data=data)
    approach, press, retract = [], [], []
    for digit in range(N_KEYS):
        r_xyz = press_point(digit) + np.array([0.0, 0.0, RETRACT_HEIGHT])
        retract.append(solve_ik(dm, r_xyz, home, data=data))
        approach.append(solve_ik(dm, approach_point(digit), retract[-1], data=data))
        press.append(solve_ik(dm, press_point(digit), approach[-1], data=data))
    return Targets(
        home=home,
        approach=np.array(approach),
        press=np.array(press),
        retract=np.array(retract),
        approach_xyz=np.array([approach_point(d) for d in range(N_KEYS)]),
        press_xyz=np.array([press_point(d) for d in range(N_KEYS)]),
        retract_xyz=np.array([press_point(d) + np.array([0, 0, RETRACT_HEIGHT]) for d in range(N_KEYS)]),
    )


@functools.lru_cache(maxsize=1)
def shared_targets() -> Targets:
    """The waypoints of :func:`~sim_nodes.dial.scene.shared_model`, solved once per process."""
    return compute_targets(shared_model())
