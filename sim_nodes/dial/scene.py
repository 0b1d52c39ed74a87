"""The Dial scene built in code with ``mujoco.MjSpec`` (docs/dial.md §1.2, §5.4, §5.6).

A Kinova JACO 6-DoF arm with its 3-finger hand, loaded from the *installed* ``dm_control``
package (``dm_control/third_party/kinova``, BSD-3-Clause, Kinova Robotics / dm_control authors;
the files are read in place and never copied into this repository), stands on a pedestal at
(0, 0, 0.25) next to a table carrying a number pad with 10 keys in telephone layout at the
original coordinates (docs/dial.md §1.2).  Every key has two sites: ``key<d>_approach`` and
``key<d>_press``.  Nine ``motor`` actuators drive the 6 arm and 3 finger joints.

Deviations from the original ``jaco_pinpad.xml`` (docs/dial.md §5.2), all deliberate:

* Arm and hand are dm_control's JACO: 60° wrist (original 55°), Kinova zero-angle convention,
  joint_2/joint_3 limited, dm_control joint dynamics (armature 4/2, frictionloss 2/1, damping
  0.01; original frictionloss 3/100/10/3/3/3, armature 0.01) and hard contacts.  The hand has two
  bodies per finger (proximal + distal) on one joint each, range [0.15, 1.35] rad.
* The finger *reference point* is the hand's ``pinchsite`` (between the finger tips), not the
  finger-3 knuckle origin used by the original.
* Press point = 2 cm above the key top, centred on the key; approach point = 4 cm above the press
  point (the original stored hand-picked poses whose finger-3 knuckle sat 10-13 cm above the key
  centre, 1.7-5.7 cm L1 from the approach pose).
* Keys are plain primitives without digit textures (the original PNG textures are not
  redistributable, docs/dial.md §5.3); the body names are ``key<digit>``, so name == digit.
* Actuators are torque motors as in the original (dm_control's own JACO uses velocity
  actuators); gear = torque scale, ``ctrlrange`` [-1, 1], so ``ctrl`` is the normalised action
  (see :data:`TORQUE_SCALE`; original gears 50/100/100/50/50/50/10/10/10 with Python-side clips).
* Collisions: the arm (dm_control contype 3 / conaffinity 2) collides with the ground, the pad and
  the keys (contype = conaffinity = 1) but not with the table top or the pedestal, like the
  original.  The expert's presses are contact-free (the press point is 2 cm above the key top).
* No camera bodies, textures or fog of the original; two cameras ``main`` (from +x, like the
  original ``camera_main``) and ``side``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

from ompn_ros.errors import OMPNError

N_KEYS = 10
TIMESTEP = 0.002
FRAME_SKIP = 20
GRAVITY = (0.0, 0.0, -9.81)

ARM_JOINTS = ("joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6")
FINGER_JOINTS = ("finger_1", "finger_2", "finger_3")
JOINT_NAMES: tuple[str, ...] = tuple(f"arm/{j}" for j in ARM_JOINTS) + tuple(
    f"arm/hand/{j}" for j in FINGER_JOINTS
)
"""Full MuJoCo names of the 9 actuated joints in observation/action order."""

TORQUE_SCALE = np.array([30.5, 30.5, 30.5, 6.8, 6.8, 6.8, 1.0, 1.0, 1.0])
"""N·m per unit of normalised action: torque_i = TORQUE_SCALE[i] * clip(action_i, -1, 1).

Arm values are dm_control's JACO actuator force limits (30.5 N·m for joints 1-3, 6.8 N·m for
joints 4-6); fingers use dm_control's finger force limit of 1."""

REFERENCE_SITE = "arm/hand/pinchsite"

# Telephone keypad (docs/dial.md §1.2): digit -> key centre (x, y) in the world frame.
KEY_XY: dict[int, tuple[float, float]] = {
    1: (0.36, 0.21), 4: (0.36, 0.07), 7: (0.36, -0.07),
    2: (0.50, 0.21), 5: (0.50, 0.07), 8: (0.50, -0.07), 0: (0.50, -0.21),
    3: (0.64, 0.21), 6: (0.64, 0.07), 9: (0.64, -0.07),
}  # fmt: skip
KEY_TOP_Z = 0.10
KEY_HALF = (0.06, 0.06, 0.01)
PAD_POS = (0.5, 0.0, 0.05)
PAD_HALF = (0.22, 0.285, 0.0495)
TABLE_POS = (0.5, 0.0, 0.0)
TABLE_HALF = (0.40, 0.40, 0.05)
ARM_BASE_POS = (0.0, 0.0, 0.25)
PRESS_HEIGHT = 0.02  # press point above the key top
APPROACH_HEIGHT = 0.04  # approach point above the press point
HOME_XYZ = (0.57, -0.33, 0.28)  # reference-point home, near the original's (0.568, -0.331, 0.275)


class DialAssetError(OMPNError, RuntimeError):
    """The dm_control Kinova JACO assets could not be found or loaded."""


def kinova_dir() -> Path:
    """Directory of the installed dm_control Kinova JACO model (never copied into the repo)."""
    try:
        root = resources.files("dm_control") / "third_party" / "kinova"
    except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
        raise DialAssetError("the 'dm_control' package is not installed; it provides the JACO model") from exc
    path = Path(str(root))
    for name in ("jaco_arm.xml", "jaco_hand.xml"):
        if not (path / name).is_file():
            raise DialAssetError(f"dm_control JACO asset '{name}' not found in {path}")
    return path


def press_point(digit: int) -> np.ndarray:
    """World position of the press point of ``digit`` (2 cm above the key top)."""
    x, y = KEY_XY[digit]
    return np.array([x, y, KEY_TOP_Z + PRESS_HEIGHT])


def approach_point(digit: int) -> np.ndarray:
    """World position of the approach point of ``digit`` (4 cm above its press point)."""
    return press_point(digit) + np.array([0.0, 0.0, APPROACH_HEIGHT])


def build_spec() -> mujoco.MjSpec:
    """Build the complete scene as an (uncompiled) ``MjSpec``."""
    kdir = kinova_dir()
    try:
        arm = mujoco.MjSpec.from_file(str(kdir / "jaco_arm.xml"))
        hand = mujoco.MjSpec.from_file(str(kdir / "jaco_hand.xml"))
    except Exception as exc:  # mujoco raises ValueError on parse/asset errors
        raise DialAssetError(f"cannot load the dm_control JACO model from {kdir}: {exc}") from exc
    arm.site("wristsite").attach_body(hand.body("hand"), "hand/", "")

    spec = mujoco.MjSpec()
    spec.modelname = "ompn_dial"
    spec.option.timestep = TIMESTEP
    spec.option.gravity = GRAVITY
    spec.visual.global_.offwidth = 800
    spec.visual.global_.offheight = 800
    spec.stat.center = (0.3, 0.0, 0.3)
    spec.stat.extent = 1.0

    world = spec.worldbody
    world.add_light(pos=(1.0, 1.0, 1.5), dir=(-1.0, -1.0, -1.3), diffuse=(1, 1, 1), specular=(0.1, 0.1, 0.1))
    world.add_light(pos=(0.0, 0.0, 3.0), dir=(0, 0, -1), diffuse=(0.4, 0.4, 0.4))
    static = {"contype": 1, "conaffinity": 1}
    world.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=(2, 2, 0.1),
                   rgba=(0.24, 0.25, 0.24, 1), **static)  # fmt: skip
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, pos=TABLE_POS, size=TABLE_HALF,
                   rgba=(0.55, 0.40, 0.25, 1), contype=0, conaffinity=0)  # fmt: skip
    pedestal = world.add_body(name="pedestal", pos=ARM_BASE_POS)
    pedestal.add_geom(name="pedestal", type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=(0, 0, -0.125),
                      size=(0.045, 0.125, 0), rgba=(0.3, 0.3, 0.32, 1), contype=0, conaffinity=0)  # fmt: skip

    pad = world.add_body(name="pinpad", pos=PAD_POS)
    pad.add_geom(name="pinpad", type=mujoco.mjtGeom.mjGEOM_BOX, size=PAD_HALF, rgba=(0.55, 0.55, 0.55, 1),
                 **static)  # fmt: skip
    for digit in range(N_KEYS):
        x, y = KEY_XY[digit]
        key = pad.add_body(name=f"key{digit}", pos=(x - PAD_POS[0], y - PAD_POS[1], 0.04))
        key.add_geom(name=f"key{digit}", type=mujoco.mjtGeom.mjGEOM_BOX, size=KEY_HALF,
                     rgba=(0.95, 0.80, 0.15, 1), **static)  # fmt: skip
        top = KEY_HALF[2]
        key.add_site(name=f"key{digit}_press", pos=(0, 0, top + PRESS_HEIGHT), size=(0.006, 0, 0),
                     rgba=(0.9, 0.1, 0.1, 0.6), group=4)  # fmt: skip
        key.add_site(name=f"key{digit}_approach", pos=(0, 0, top + PRESS_HEIGHT + APPROACH_HEIGHT),
                     size=(0.006, 0, 0), rgba=(0.1, 0.3, 0.9, 0.6), group=4)  # fmt: skip

    world.add_camera(name="main", pos=(1.55, 0.0, 1.05), xyaxes=(0, 1, 0, -0.55, 0, 0.83))
    world.add_camera(name="side", pos=(0.45, -1.35, 0.85), xyaxes=(1, 0, 0, 0, 0.5, 0.87))

    frame = pedestal.add_frame()
    spec.attach(arm, prefix="arm/", frame=frame)

    for joint, scale in zip(JOINT_NAMES, TORQUE_SCALE, strict=True):
        act = spec.add_actuator(name=joint.rsplit("/", 1)[-1], target=joint,
                                trntype=mujoco.mjtTrn.mjTRN_JOINT)  # fmt: skip
        act.gear[0] = float(scale)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = (-1.0, 1.0)
    return spec


@dataclass(frozen=True)
class DialModel:
    """A compiled scene plus the indices the env and expert need."""

    model: mujoco.MjModel
    qpos_adr: np.ndarray  # [9] qpos addresses of the 9 joints (obs/action order)
    dof_adr: np.ndarray  # [9] dof addresses
    reference_site: int
    press_sites: np.ndarray  # [10] site ids, by digit
    approach_sites: np.ndarray  # [10] site ids, by digit
    joint_range: np.ndarray  # [9, 2]; (-inf, inf) for unlimited joints


def compile_model() -> DialModel:
    """Compile a fresh scene (a new ``MjModel`` each call)."""
    try:
        model = build_spec().compile()
    except ValueError as exc:
        raise DialAssetError(f"compiling the Dial scene failed: {exc}") from exc
    jids = [model.joint(n).id for n in JOINT_NAMES]
    rng = np.array(model.jnt_range[jids], dtype=float)
    limited = model.jnt_limited[jids].astype(bool)
    rng[~limited] = (-np.inf, np.inf)
    return DialModel(
        model=model,
        qpos_adr=np.array(model.jnt_qposadr[jids]),
        dof_adr=np.array(model.jnt_dofadr[jids]),
        reference_site=model.site(REFERENCE_SITE).id,
        press_sites=np.array([model.site(f"key{d}_press").id for d in range(N_KEYS)]),
        approach_sites=np.array([model.site(f"key{d}_approach").id for d in range(N_KEYS)]),
        joint_range=rng,
    )


@functools.lru_cache(maxsize=1)
def shared_model() -> DialModel:
    """One compiled scene per process (``MjModel`` is read-only once compiled)."""
    return compile_model()
