"""KUKA LBR iiwa (7 joints), from ``pybullet_data/kuka_iiwa/model.urdf``.

The URDF's joint damping (0.5 N·m·s/rad) is zeroed at load, like every arm here. Its
``effort`` of 300 N·m per joint is not the robot's: the torque limits below are those of
the KUKA LBR iiwa 7 R800 data sheet (176, 176, 110, 110, 110, 40, 40 N·m).
"""

from __future__ import annotations

import os

import pybullet_data

from ptrack_gym.robots.profile import DisturbanceScales, EECircle, RobotProfile

_LIMIT_1 = 2.96705972839  # rad, joints 1, 3, 5
_LIMIT_2 = 2.09439510239  # rad, joints 2, 4, 6
_LIMIT_7 = 3.05432619099  # rad, joint 7

PROFILE = RobotProfile(
    name="iiwa",
    env_name="Iiwa",
    urdf=os.path.join(pybullet_data.getDataPath(), "kuka_iiwa", "model.urdf"),
    joint_names=tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8)),
    torque_limits_nm=(176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0),
    joint_lower_rad=(-_LIMIT_1, -_LIMIT_2, -_LIMIT_1, -_LIMIT_2, -_LIMIT_1, -_LIMIT_2, -_LIMIT_7),
    joint_upper_rad=(_LIMIT_1, _LIMIT_2, _LIMIT_1, _LIMIT_2, _LIMIT_1, _LIMIT_2, _LIMIT_7),
    home_q_rad=(0.0, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0),
    path_amplitude_rad=(0.4, 0.3, 0.4, 0.3, 0.4, 0.3, 0.4),
    path_period_s=8.0,
    ee_link="lbr_iiwa_link_7",
    circle=EECircle(center_m=(0.5, 0.0, 0.6), radius_m=0.1, normal=(1.0, 0.0, 0.0)),
    disturbance_scales=DisturbanceScales(
        impulse_j=1.0,
        push_n=40.0,
        payload_kg=2.0,
        mismatch_links=tuple(f"lbr_iiwa_link_{i}" for i in range(1, 8)),
    ),
    default_control_hz=500.0,
    # Rates of the gain studies (docs/passivity_gain_study.md, docs/baselines.md). The
    # passivity default adds the low-speed phase re-synchronisation of σ (γ = 0.5 1/s below
    # speed ratio 0.5; not in the paper): it frees the stall trap of some rest starts.
    controller_gains={
        "passivity": {
            "omega": 20.0,
            "omega_s": 20.0,
            "rho": 10.0,
            "lam": 2.0,
            "m_floor": 0.1,
            "sync_rate": 0.5,
            "sync_ratio": 0.5,
        },
        "computed_torque": {"omega": 20.0},
        "computed_torque_observer": {"omega": 20.0},
        "computed_torque_path": {"omega": 20.0},
        "pd_gravity": {"omega": 20.0},
        "pid_gravity": {"omega": 20.0},
        "slotine_li": {"omega": 20.0},
        "adaptive_slotine_li": {"omega": 20.0},
    },
    convergence_target_s=25.0,
    camera_target_m=(0.0, 0.0, 0.6),
    camera_distance_m=1.6,
    source="pybullet_data kuka_iiwa/model.urdf; torque limits: KUKA LBR iiwa 7 R800 data sheet",
)
