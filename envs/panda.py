"""The Franka Emika Panda on a table, written as MJCF here (no downloaded assets).

Kinematics follow Franka's published parameters (link offsets 0.333, 0.316, 0.0825,
-0.0825 / 0.384, 0.088, flange 0.107; hand rotated -45 deg about the flange axis;
tool-centre point 0.1034 m past the flange). Masses, centres of mass and inertias
are rounded values of the published dynamic identification. Collision geometry is
capsules and boxes only, and contacts come from explicit ``<pair>`` elements (every
geom has contype = conaffinity = 0), so MJX checks only the pairs a scene needs.

A scene is ``scene_xml(objects=..., pairs=...)``: tasks add their bodies and the
contact pairs between their geoms and :data:`GRIPPER_GEOMS` / ``"table"``.
"""
from __future__ import annotations

import numpy as np

TABLE_HEIGHT = 0.75
ROBOT_BASE = (0.0, 0.0, TABLE_HEIGHT)
CAMERA_NAME = "front"
# The front camera: ~1.65 m in front of the base along x, 1.88 m high, looking at the workspace.
CAMERA_POS = (1.65, 0.0, 1.88)
CAMERA_TARGET = (0.3, 0.0, TABLE_HEIGHT + 0.12)
CAMERA_FOVY = 40.0
#: Largest image side the offscreen framebuffer can render (the scene's ``offwidth`` / ``offheight``).
MAX_IMAGE_SIZE = 512

ARM_JOINTS = tuple(f"joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("finger_left", "finger_right")
TCP_SITE = "tcp"
#: Arm posture the robot starts in: gripper pointing down above the table.
HOME_QPOS = (0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785)
GRIPPER_OPEN = 0.04  # metres per finger
#: Robot geoms that touch objects (contact pairs are made against these).
GRIPPER_GEOMS = ("hand_col", "finger_left_pad", "finger_right_pad")

# (name, pos in parent, quat in parent (wxyz), joint range, mass, com, diaginertia,
#  offset to the child's origin for the visual/collision segment, segment radius)
_LINKS = (
    ("link1", (0, 0, 0.333), (1, 0, 0, 0), (-2.8973, 2.8973), 4.97, (0.0, -0.004, -0.103),
     (0.70337, 0.70661, 0.00911), None, 0.06),
    ("link2", (0, 0, 0), (1, -1, 0, 0), (-1.7628, 1.7628), 0.646, (0.0, -0.070, 0.003),
     (0.00796, 0.02811, 0.02600), (0, -0.316, 0), 0.06),
    ("link3", (0, -0.316, 0), (1, 1, 0, 0), (-2.8973, 2.8973), 3.228, (0.027, 0.039, -0.066),
     (0.03724, 0.03616, 0.01083), (0.0825, 0, 0), 0.055),
    ("link4", (0.0825, 0, 0), (1, 1, 0, 0), (-3.0718, -0.0698), 3.587, (-0.053, 0.104, 0.027),
     (0.02585, 0.01955, 0.02832), (-0.0825, 0.384, 0), 0.055),
    ("link5", (-0.0825, 0.384, 0), (1, -1, 0, 0), (-2.8973, 2.8973), 1.226, (-0.012, 0.041, -0.038),
     (0.03555, 0.02947, 0.00863), None, 0.05),
    ("link6", (0, 0, 0), (1, 1, 0, 0), (-0.0175, 3.7525), 1.666, (0.060, -0.014, -0.010),
     (0.00196, 0.00435, 0.00543), (0.088, 0, 0), 0.045),
    ("link7", (0.088, 0, 0), (1, 1, 0, 0), (-2.8973, 2.8973), 0.735, (0.010, -0.004, 0.061),
     (0.01252, 0.01003, 0.00482), (0, 0, 0.107), 0.04),
)
# Position servo gains per joint (N m / rad), damping (N m s / rad) and torque limits (N m).
_KP = (4500, 4500, 3500, 3500, 2000, 2000, 2000)
_KV = (450, 450, 350, 350, 200, 200, 200)
_TORQUE = (87, 87, 87, 87, 12, 12, 12)

_WHITE = "0.95 0.95 0.95 1"
_DARK = "0.15 0.15 0.17 1"


def _fmt(v) -> str:
    return " ".join(f"{x:.6g}" for x in v)


def _camera_xyaxes() -> tuple[float, ...]:
    pos, target = np.array(CAMERA_POS), np.array(CAMERA_TARGET)
    forward = (target - pos) / np.linalg.norm(target - pos)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return (*right, *up)


def _segment(name: str, to, radius: float, rgba: str) -> str:
    """A visual capsule and its collision twin from the body origin to ``to``."""
    frm = _fmt((0, 0, 0))
    return (
        f'<geom name="{name}_vis" type="capsule" fromto="{frm} {_fmt(to)}" size="{radius}" '
        f'class="visual" rgba="{rgba}"/>'
        f'<geom name="{name}_col" type="capsule" fromto="{frm} {_fmt(to)}" size="{radius * 0.9:.4g}" '
        f'class="collision"/>'
    )


def _hand_xml(tcp_marker: bool) -> str:
    fingers = []
    for side, sign in (("left", 1), ("right", -1)):
        fingers.append(
            f'<body name="finger_{side}" pos="0 0 0.0584">'
            f'<inertial pos="0 {0.01 * sign} 0.03" mass="0.015" diaginertia="2.4e-6 2.4e-6 8e-7"/>'
            f'<joint name="finger_{side}" type="slide" axis="0 {sign} 0" range="0 0.04" '
            f'damping="5" armature="0.1"/>'
            f'<geom name="finger_{side}_vis" type="box" size="0.011 0.009 0.027" '
            f'pos="0 {0.009 * sign} 0.027" class="visual" rgba="{_WHITE}"/>'
            f'<geom name="finger_{side}_pad" type="box" size="0.01 0.006 0.02" '
            f'pos="0 {0.006 * sign} 0.035" class="collision" friction="1.5 0.01 0.001"/>'
            "</body>"
        )
    return (
        '<body name="hand" pos="0 0 0.107" quat="0.92388 0 0 -0.382683">'
        '<inertial pos="0 0 0.03" mass="0.73" diaginertia="0.001 0.0025 0.0017"/>'
        f'<geom name="hand_vis" type="box" size="0.03 0.1 0.025" pos="0 0 0.03" class="visual" '
        f'rgba="{_WHITE}"/>'
        f'<geom name="hand_cap_vis" type="cylinder" size="0.04 0.008" pos="0 0 0.006" class="visual" '
        f'rgba="{_DARK}"/>'
        '<geom name="hand_col" type="box" size="0.028 0.095 0.022" pos="0 0 0.03" class="collision"/>'
        + "".join(fingers)
        + f'<site name="{TCP_SITE}" pos="0 0 0.1034" size="0.006" rgba="1 0.2 0.2 1" group="4"/>'
        + ('<geom name="tcp_marker" type="sphere" size="0.008" pos="0 0 0.1034" class="visual" '
           'rgba="1 0 1 1"/>' if tcp_marker else "")
        + "</body>"
    )


def robot_xml(tcp_marker: bool = False) -> str:
    """The arm as a nested ``<body>`` chain rooted at the robot base. ``tcp_marker`` adds a
    small visible sphere at the tool-centre point (for camera checks and figures)."""
    inner = _hand_xml(tcp_marker)
    for i, (name, pos, quat, rng, mass, com, inertia, child, radius) in reversed(
        list(enumerate(_LINKS))
    ):
        joint = ARM_JOINTS[i]
        body = (
            f'<body name="{name}" pos="{_fmt(pos)}" quat="{_fmt(quat)}" gravcomp="1">'
            f'<inertial pos="{_fmt(com)}" mass="{mass}" diaginertia="{_fmt(inertia)}"/>'
            f'<joint name="{joint}" axis="0 0 1" range="{rng[0]} {rng[1]}" class="arm"/>'
            f'<geom name="{name}_housing" type="cylinder" size="{radius * 1.05:.4g} {radius * 1.1:.4g}" '
            f'class="visual" rgba="{_DARK if i % 2 else _WHITE}"/>'
        )
        if child is not None:
            body += _segment(name, child, radius, _WHITE)
        inner = body + inner + "</body>"
    base = (
        f'<body name="link0" pos="{_fmt(ROBOT_BASE)}">'
        '<geom name="link0_vis" type="cylinder" size="0.075 0.07" pos="0 0 0.07" class="visual" '
        f'rgba="{_WHITE}"/>'
        '<geom name="link0_neck_vis" type="capsule" fromto="0 0 0.1 0 0 0.2" size="0.062" class="visual" '
        f'rgba="{_WHITE}"/>'
        '<geom name="link0_back_vis" type="box" size="0.06 0.07 0.05" pos="-0.09 0 0.05" class="visual" '
        f'rgba="{_DARK}"/>' + inner + "</body>"
    )
    return base


def _actuators_xml() -> str:
    arm = "".join(
        f'<position name="act_{j}" joint="{j}" kp="{kp}" kv="{kv}" forcerange="{-t} {t}" '
        f'ctrlrange="{lo} {hi}"/>'
        for j, kp, kv, t, (lo, hi) in zip(ARM_JOINTS, _KP, _KV, _TORQUE, (link[3] for link in _LINKS))
    )
    # One command opens both fingers: a tendon averages them, an equality keeps them equal.
    grip = (
        f'<position name="act_gripper" tendon="grip" kp="400" kv="20" forcerange="-70 70" '
        f'ctrlrange="0 {GRIPPER_OPEN}"/>'
    )
    return f"<actuator>{arm}{grip}</actuator>"


def scene_xml(objects: str = "", pairs: tuple[tuple[str, str], ...] = (), extra_assets: str = "",
              tcp_marker: bool = False) -> str:
    """A complete MJCF: table, Panda, front camera, lights, and a task's ``objects``.

    Args:
      objects: MJCF bodies to put in the worldbody (geoms should use class
        ``"object"`` for collision geoms, ``"visual"`` for decoration).
      pairs: contact pairs (geom1, geom2) to add to the robot-table pairs.
      extra_assets: MJCF ``<asset>`` children (textures, materials) the objects use.
      tcp_marker: draw a small sphere at the tool-centre point.
    """
    robot_table = tuple((g, "table") for g in GRIPPER_GEOMS)
    pair_xml = "".join(
        f'<pair geom1="{a}" geom2="{b}" condim="4" friction="1.5 1.5 0.01 0.0001 0.0001"/>'
        if a in GRIPPER_GEOMS or b in GRIPPER_GEOMS
        else f'<pair geom1="{a}" geom2="{b}" condim="3" friction="0.8 0.8 0.005 0.0001 0.0001"/>'
        for a, b in robot_table + tuple(pairs)
    )
    table_top = TABLE_HEIGHT
    return f"""<mujoco model="panda_table">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.004" iterations="6" ls_iterations="8" integrator="implicitfast" cone="pyramidal">
    <flag eulerdamp="disable"/>
  </option>
  <visual>
    <global offwidth="{MAX_IMAGE_SIZE}" offheight="{MAX_IMAGE_SIZE}"/>
    <quality shadowsize="2048"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5" specular="0.1 0.1 0.1"/>
  </visual>
  <default>
    <geom contype="0" conaffinity="0"/>
    <default class="visual"><geom group="1" mass="0" density="0"/></default>
    <default class="collision"><geom group="3" rgba="0.5 0.5 0.9 0.3" mass="0" density="0"/></default>
    <default class="object"><geom group="2" friction="1 0.01 0.001" solref="0.005 1"/></default>
    <default class="arm"><joint armature="0.1" damping="1" frictionloss="0.1"/></default>
  </default>
  <asset>
    <texture name="floor_tex" type="2d" builtin="checker" rgb1="0.32 0.34 0.36" rgb2="0.28 0.3 0.32"
      width="256" height="256"/>
    <material name="floor_mat" texture="floor_tex" texrepeat="6 6"/>
    <texture name="wood_tex" type="2d" builtin="flat" rgb1="0.62 0.5 0.38" width="64" height="64"/>
    <material name="table_mat" texture="wood_tex" specular="0.1"/>
    {extra_assets}
  </asset>
  <worldbody>
    <light name="key" pos="1.2 -0.8 2.6" dir="-0.4 0.3 -1" diffuse="0.6 0.6 0.6" castshadow="true"/>
    <light name="fill" pos="0.2 1.2 2.4" dir="0 -0.4 -1" diffuse="0.3 0.3 0.3" castshadow="false"/>
    <geom name="floor" type="plane" size="4 4 0.1" material="floor_mat" class="visual"/>
    <geom name="table_vis" type="box" size="0.65 0.75 0.025" pos="0.35 0 {table_top - 0.025}"
      material="table_mat" class="visual"/>
    <geom name="table_leg_vis" type="box" size="0.6 0.7 {(table_top - 0.05) / 2:.4g}"
      pos="0.35 0 {(table_top - 0.05) / 2:.4g}" rgba="0.4 0.33 0.25 1" class="visual"/>
    <geom name="table" type="plane" size="0.65 0.75 0.01" pos="0.35 0 {table_top}" group="3"
      rgba="0 0 0 0"/>
    <camera name="{CAMERA_NAME}" pos="{_fmt(CAMERA_POS)}" xyaxes="{_fmt(_camera_xyaxes())}"
      fovy="{CAMERA_FOVY}"/>
    {robot_xml(tcp_marker)}
    {objects}
  </worldbody>
  <tendon>
    <fixed name="grip"><joint joint="finger_left" coef="0.5"/><joint joint="finger_right" coef="0.5"/></fixed>
  </tendon>
  <equality>
    <joint joint1="finger_left" joint2="finger_right" solref="0.005 1"/>
  </equality>
  <contact>{pair_xml}</contact>
  {_actuators_xml()}
</mujoco>"""


def cube_xml(name: str = "cube", pos=(0.5, 0.0, TABLE_HEIGHT + 0.025), half: float = 0.025,
             rgba: str = "0.85 0.2 0.15 1", mass: float = 0.1) -> str:
    """A free cube (used by the default scene and tests)."""
    return (
        f'<body name="{name}" pos="{_fmt(pos)}"><freejoint name="{name}_free"/>'
        f'<geom name="{name}" type="box" size="{half} {half} {half}" mass="{mass}" class="object" '
        f'rgba="{rgba}"/></body>'
    )


def default_scene_xml(tcp_marker: bool = False) -> str:
    """Panda, table and one red cube: the scene of ``bin/render`` and ``bin/execute``."""
    return scene_xml(
        tcp_marker=tcp_marker,
        objects=cube_xml(),
        pairs=tuple((g, "cube") for g in ("table",) + GRIPPER_GEOMS),
    )
