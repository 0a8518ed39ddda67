"""Franka Emika Panda (7 arm joints), from ``pybullet_data/franka_panda/panda.urdf``.

The two finger joints are **locked**: the URDF is rewritten with them ``fixed`` (fingers
closed), so the fingers' masses ride rigidly on the hand and the model has exactly the 7
arm joints. Mesh paths are made absolute so the rewritten file loads from anywhere.
Torque limits (87 ×4, 12 ×3 N·m) and joint limits are the URDF's (Franka's data sheet).
"""

from __future__ import annotations

import os
import re

import pybullet_data

from ptrack_gym.robots.spec import RobotSpec, materialize_urdf

_FINGERS = ("panda_finger_joint1", "panda_finger_joint2")


def locked_finger_urdf() -> str:
    """The Panda URDF text with finger joints fixed and absolute mesh paths."""
    folder = os.path.join(pybullet_data.getDataPath(), "franka_panda")
    with open(os.path.join(folder, "panda.urdf")) as f:
        text = f.read()
    text = text.replace('filename="package://', f'filename="{folder}/')
    for name in _FINGERS:
        text, count = re.subn(
            rf'<joint name="{name}" type="prismatic">', f'<joint name="{name}" type="fixed">', text
        )
        if count != 1:  # pragma: no cover - only if pybullet_data changes
            raise RuntimeError(f"could not lock {name} in panda.urdf")
    # A fixed joint takes no <mimic>; drop it so the loader does not warn.
    return re.sub(r'\s*<mimic joint="panda_finger_joint1"/>', "", text)


def panda() -> RobotSpec:
    """The Panda's spec (fingers locked)."""
    return RobotSpec(
        name="panda",
        urdf_path=materialize_urdf("panda_locked_fingers", locked_finger_urdf()),
        joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
        torque_limits_nm=(87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0),
        joint_lower_rad=(-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671),
        joint_upper_rad=(2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671),
        home_q_rad=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
        path_amplitude_rad=(0.4, 0.3, 0.4, 0.3, 0.4, 0.3, 0.4),
        ee_link="panda_grasptarget",
        camera_target_m=(0.0, 0.0, 0.5),
        camera_distance_m=1.5,
    )
