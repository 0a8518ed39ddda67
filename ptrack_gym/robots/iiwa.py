"""KUKA LBR iiwa (7 joints), from ``pybullet_data/kuka_iiwa/model.urdf``.

The URDF's joint damping (0.5 N·m·s/rad) is zeroed at load, like every arm here. Its
``effort`` of 300 N·m per joint is not the robot's: the torque limits below are those
of the KUKA LBR iiwa 7 R800 data sheet (176, 176, 110, 110, 110, 40, 40 N·m).
"""

from __future__ import annotations

import os

import pybullet_data

from ptrack_gym.robots.spec import RobotSpec

_LIMIT_1 = 2.96705972839  # rad, joints 1, 3, 5
_LIMIT_2 = 2.09439510239  # rad, joints 2, 4, 6
_LIMIT_7 = 3.05432619099  # rad, joint 7


def iiwa() -> RobotSpec:
    """The iiwa's spec."""
    return RobotSpec(
        name="iiwa",
        urdf_path=os.path.join(pybullet_data.getDataPath(), "kuka_iiwa", "model.urdf"),
        joint_names=tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8)),
        torque_limits_nm=(176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0),
        joint_lower_rad=(
            -_LIMIT_1,
            -_LIMIT_2,
            -_LIMIT_1,
            -_LIMIT_2,
            -_LIMIT_1,
            -_LIMIT_2,
            -_LIMIT_7,
        ),
        joint_upper_rad=(_LIMIT_1, _LIMIT_2, _LIMIT_1, _LIMIT_2, _LIMIT_1, _LIMIT_2, _LIMIT_7),
        home_q_rad=(0.0, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0),
        path_amplitude_rad=(0.4, 0.3, 0.4, 0.3, 0.4, 0.3, 0.4),
        ee_link="lbr_iiwa_link_7",
        camera_target_m=(0.0, 0.0, 0.6),
        camera_distance_m=1.6,
    )
