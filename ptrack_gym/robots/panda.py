"""Franka Emika Panda (7 arm joints), from ``pybullet_data/franka_panda/panda.urdf``.

The kinematics are pybullet_data's (identical to franka_ros's up to 5e-12 rad of rpy
rounding). Its inertials are placeholders (0.1·I kg·m² on every link, which inflates the
wrist's joint inertias 3-4×), so the URDF is rewritten with the published franka_ros link
masses, centres of mass and inertia tensors — the ``panda.urdf`` of Gepetto's
example-robot-data (commit 39aa943, file at 17d69f9; from franka_ros
``franka_description/robots/common/inertial.yaml``). Franka marks those values as not
official: they are the identification of Gaz et al., "Dynamic Identification of the Franka
Emika Panda Robot With Retrieval of Feasible Parameters Using Penalty-Based Optimization",
IEEE RA-L 2019.

The two finger joints are **locked**: the URDF is rewritten with them ``fixed`` (fingers
closed), so the fingers' masses ride rigidly on the hand and the model has exactly the 7
arm joints. Mesh paths are made absolute so the rewritten file loads from anywhere. Torque
limits (87 ×4, 12 ×3 N·m) are the URDF's and Franka's; the joint limits are Franka's FCI
limits (franka_ros ``joint_limits.yaml``), 4° inside the wider ones pybullet_data writes.
"""

from __future__ import annotations

import os
import re

import pybullet_data

from ptrack_gym.robots.profile import (
    DisturbanceScales,
    EECircle,
    Inertial,
    RobotProfile,
    absolute_mesh_paths,
    replace_inertials,
)

_FINGERS = ("panda_finger_joint1", "panda_finger_joint2")

#: franka_ros inertials (kg; m; kg·m²: ixx, ixy, ixz, iyy, iyz, izz), example-robot-data.
#: The fixed base (panda_link0) keeps pybullet_data's inertial: a base's inertia has no
#: effect on a fixed-base arm, and PyBullet's inverse dynamics mishandles a base inertial
#: frame that is offset and rotated (measured: gravity torques off by up to 4 N·m against
#: Pinocchio and against PyBullet's own forward dynamics, with link0's published block).
FRANKA_ROS_INERTIALS: dict[str, Inertial] = {
    "panda_link1": Inertial(
        4.970684, (0.003875, 0.002081, -0.04762),
        (0.70337, -0.000139, 0.006772, 0.70661, 0.019169, 0.009117),
    ),
    "panda_link2": Inertial(
        0.646926, (-0.003141, -0.02872, 0.003495),
        (0.007962, -0.003925, 0.010254, 0.02811, 0.000704, 0.025995),
    ),
    "panda_link3": Inertial(
        3.228604, (2.7518e-02, 3.9252e-02, -6.6502e-02),
        (0.037242, -0.004761, -0.011396, 0.036155, -0.012805, 0.01083),
    ),
    "panda_link4": Inertial(
        3.587895, (-5.317e-02, 1.04419e-01, 2.7454e-02),
        (0.025853, 0.007796, -0.001332, 0.019552, 0.008641, 0.028323),
    ),
    "panda_link5": Inertial(
        1.225946, (-1.1953e-02, 4.1065e-02, -3.8437e-02),
        (0.035549, -0.002117, -0.004037, 0.029474, 0.000229, 0.008627),
    ),
    "panda_link6": Inertial(
        1.666555, (6.0149e-02, -1.4117e-02, -1.0517e-02),
        (0.001964, 0.000109, -0.001158, 0.004354, 0.000341, 0.005433),
    ),
    "panda_link7": Inertial(
        0.735522, (1.0517e-02, -4.252e-03, 6.1597e-02),
        (0.012516, -0.000428, -0.001196, 0.010027, -0.000741, 0.004815),
    ),
    "panda_hand": Inertial(0.73, (-0.01, 0.0, 0.03), (0.001, 0.0, 0.0, 0.0025, 0.0, 0.0017)),
    "panda_leftfinger": Inertial(
        0.015, (0.0, 0.0, 0.0), (2.375e-06, 0.0, 0.0, 2.375e-06, 0.0, 7.5e-07)
    ),
    "panda_rightfinger": Inertial(
        0.015, (0.0, 0.0, 0.0), (2.375e-06, 0.0, 0.0, 2.375e-06, 0.0, 7.5e-07)
    ),
    # Frames, not bodies: pybullet_data gives these massless links a 0.1 kg·m² inertia each,
    # which rides on joint 7 (M's wrist diagonal 0.24/0.25/0.21 kg·m² at q = 0 instead of
    # franka_ros' 0.03/0.03/0.006); franka_ros gives them no inertial at all.
    "panda_link8": Inertial(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
    "panda_grasptarget": Inertial(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
}  # fmt: skip


def locked_finger_urdf() -> str:
    """The Panda URDF with franka_ros inertials, finger joints fixed, absolute mesh paths."""
    folder = os.path.join(pybullet_data.getDataPath(), "franka_panda")
    with open(os.path.join(folder, "panda.urdf")) as f:
        text = f.read()
    text = absolute_mesh_paths(text, folder)
    for name in _FINGERS:
        text, count = re.subn(
            rf'<joint name="{name}" type="prismatic">', f'<joint name="{name}" type="fixed">', text
        )
        if count != 1:  # pragma: no cover - only if pybullet_data changes
            raise RuntimeError(f"could not lock {name} in panda.urdf")
    # A fixed joint takes no <mimic>; drop it so the loader does not warn.
    text = re.sub(r'\s*<mimic joint="panda_finger_joint1"/>', "", text)
    return replace_inertials(text, FRANKA_ROS_INERTIALS)


PROFILE = RobotProfile(
    name="panda",
    env_name="Panda",
    urdf=locked_finger_urdf,
    joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
    torque_limits_nm=(87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0),
    joint_lower_rad=(-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973),
    joint_upper_rad=(2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973),
    home_q_rad=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
    path_amplitude_rad=(0.4, 0.3, 0.4, 0.3, 0.4, 0.3, 0.4),
    path_period_s=8.0,
    ee_link="panda_grasptarget",
    circle=EECircle(center_m=(0.45, 0.0, 0.4), radius_m=0.1, normal=(1.0, 0.0, 0.0)),
    disturbance_scales=DisturbanceScales(
        impulse_j=1.0,
        push_n=20.0,
        payload_kg=1.0,
        mismatch_links=tuple(f"panda_link{i}" for i in range(1, 8)),
    ),
    default_control_hz=500.0,
    controller_gains={
        # The phase defect of σ (s̃ held ≈ −2e-3 s at nominal speed, mapped through K⁻¹M
        # into a transverse residual) needs the re-synchronisation to act at nominal speed
        # too (r̄ = 2 > 1).
        "passivity": {
            "omega": 15.0,
            "omega_s": 20.0,
            "rho": 10.0,
            "lam": 2.0,
            "m_floor": 0.1,
            "sync_rate": 1.0,
            "sync_ratio": 2.0,
        },
        # bench/baseline_gain_study.py with the franka_ros inertials: the largest ω of the
        # sweep with no clipped torque from rest 0.1 rad off the path (ω = 20 clips).
        "computed_torque": {"omega": 14.0},
        "computed_torque_observer": {"omega": 14.0},
        "computed_torque_path": {"omega": 14.0},
        "pd_gravity": {"omega": 14.0},
        "pid_gravity": {"omega": 14.0},
        "slotine_li": {"omega": 14.0},
        "adaptive_slotine_li": {"omega": 14.0},
    },
    convergence_target_s=30.0,
    camera_target_m=(0.0, 0.0, 0.5),
    camera_distance_m=1.5,
    source="pybullet_data franka_panda/panda.urdf, fingers locked, with franka_ros inertials "
    "(example-robot-data); FCI joint limits",
)
