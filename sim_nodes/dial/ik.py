"""Damped least-squares inverse kinematics on the reference site (``mj_jacSite``/``mj_jacBody``).

The task is 5-D: the reference site's position plus "hand pointing straight down" (the hand
body's z axis, which points from the finger tips to the wrist, aligned with world +z).  The
remaining freedom (yaw about the vertical, elbow configuration) is fixed by a weak null-space
pull toward the seed posture, so chained solves stay on one IK branch.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim_nodes.dial.scene import DialModel


class IKError(RuntimeError):
    """Inverse kinematics did not converge to the requested target."""


def solve_ik(
    dm: DialModel,
    target: np.ndarray,
    seed_q: np.ndarray,
    *,
    data: mujoco.MjData | None = None,
    iterations: int = 300,
    damping: float = 1e-3,
    tol: float = 1e-5,
    null_gain: float = 0.02,
) -> np.ndarray:
    """Joint angles [9] placing the reference site at ``target`` with the hand vertical.

    Finger joints keep their seed values.  Raises :class:`IKError` if the residual stays above
    1 mm / 0.5 deg.
    """
    m = dm.model
    d = mujoco.MjData(m) if data is None else data
    arm = dm.dof_adr[:6]
    hand_body = m.site_bodyid[dm.reference_site]
    q = np.array(seed_q, dtype=float)
    jacp = np.zeros((3, m.nv))
    jacr = np.zeros((3, m.nv))
    up = np.array([0.0, 0.0, 1.0])
    err = np.inf
    for _ in range(iterations):
        d.qpos[dm.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        pos_err = target - d.site_xpos[dm.reference_site]
        z_axis = d.xmat[hand_body].reshape(3, 3)[:, 2]
        rot_err = np.cross(z_axis, up)
        e = np.concatenate([pos_err, 0.3 * rot_err])
        err = float(np.linalg.norm(pos_err) + np.linalg.norm(rot_err) * 0.1)
        if err < tol:
            break
        mujoco.mj_jacSite(m, d, jacp, None, dm.reference_site)
        mujoco.mj_jacBody(m, d, None, jacr, hand_body)
        jac = np.vstack([jacp[:, arm], 0.3 * jacr[:, arm]])
        jjt = jac @ jac.T + damping * np.eye(6)
        pinv = jac.T @ np.linalg.solve(jjt, np.eye(6))
        null = (np.eye(6) - pinv @ jac) @ (null_gain * (seed_q[:6] - q[:6]))
        dq = pinv @ e + null
        q[:6] += np.clip(dq, -0.2, 0.2)
        lo, hi = dm.joint_range[:6, 0], dm.joint_range[:6, 1]
        q[:6] = np.clip(q[:6], lo + 1e-3, hi - 1e-3)
    d.qpos[dm.qpos_adr] = q
    mujoco.mj_kinematics(m, d)
    pos_res = float(np.linalg.norm(target - d.site_xpos[dm.reference_site]))
    tilt = float(np.degrees(np.arccos(np.clip(d.xmat[hand_body].reshape(3, 3)[2, 2], -1, 1))))
    if pos_res > 1e-3 or tilt > 0.5:
        raise IKError(
            f"IK for target {np.round(target, 4).tolist()} did not converge: "
            f"position error {pos_res * 1000:.2f} mm, hand tilt {tilt:.2f} deg"
        )
    return q
