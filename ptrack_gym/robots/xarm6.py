"""UFactory xArm6 (6 joints), from ``pybullet_data/xarm/xarm6_robot.urdf``.

The kinematics are pybullet_data's (identical to UFactory's ``xarm6_default_kinematics``).
Its link inertials are not: they are UFactory's values of 2019-2023 with the products of
inertia of the wrong sign, so link2 and link3 violate the triangle inequality and PyBullet
zeroes their rotational inertia at load (Pinocchio keeps them: the two would disagree). The
URDF is therefore rewritten with UFactory's current default inertials, xArm6 "HT_BR2"
(xArm-Developer/xarm_ros ``xarm_description/config/link_inertial/xarm6_type6_HT_BR2.yaml``,
commit 0b5118e; identical in xarm_ros2 humble and jazzy; ``link_base`` keeps the xacro's
2.7 kg): 12.05 kg in all against the data sheet's 12.2 kg, every tensor physical.

Torque limits: UFactory publishes no joint-torque table; the only published figures are the
``effort`` attributes of its URDF, 50, 50, 32, 32, 32, 20 N·m (``xarm_description/urdf/
xarm6/xarm6.urdf.xacro`` lines 103-257, unchanged since 2019, and pybullet_data's file), so
those are the limits here. They look like rated, not peak, torques: holding the rated 5 kg
payload at full reach would need ~68 N·m at joint 2. Joint limits: the URDF's (= the
xArm-Python-SDK's). The URDF's joint damping of 1 N·m·s/rad is zeroed at load, as for every
arm (with it, PyBullet's explicit damping makes the 1.4e-4 kg·m² wrist blow up at 1 kHz).
"""

from __future__ import annotations

import os

import pybullet_data

from ptrack_gym.robots.profile import (
    DisturbanceScales,
    EECircle,
    Inertial,
    RobotProfile,
    absolute_mesh_paths,
    replace_inertials,
)

#: UFactory's xArm6 HT_BR2 inertials (kg; m; kg·m²: ixx, ixy, ixz, iyy, iyz, izz).
HT_BR2_INERTIALS: dict[str, Inertial] = {
    "link1": Inertial(
        2.3814, (0.00022, 0.02951, -0.0124),
        (0.0058562, -1.79e-05, 3.55e-06, 0.0050316, -0.000888336, 0.003536652),
    ),
    "link2": Inertial(
        2.2675, (0.03881, -0.22783, 0.03496),
        (0.028315776, 0.005, 0.00066546, 0.0058, -0.0045741, 0.0273447),
    ),
    "link3": Inertial(
        1.875, (0.07041, 0.11631, 0.0107),
        (0.0063483, -0.0015397, 0.00096858, 0.00379758, 0.00186567, 0.00595768),
    ),
    "link4": Inertial(
        1.3192, (-0.00018, 0.01798, -0.02291),
        (0.004896, -6.925e-06, -1.418e-05, 0.00445694, -0.00023186, 0.00134332),
    ),
    "link5": Inertial(
        1.33854, (0.0651, 0.03096, 0.00315),
        (0.00146378, -0.000450624, 0.000284306, 0.00184192, 0.000130866, 0.002333524),
    ),
    "link6": Inertial(
        0.17, (0.0, -0.00677, -0.01098), (9.3e-05, 0.0, 0.0, 5.87e-05, -3.6e-06, 0.000132)
    ),
}  # fmt: skip

_TWO_PI = 6.28318530718


def xarm6_urdf() -> str:
    """pybullet_data's xArm6 URDF with UFactory's HT_BR2 inertials and absolute mesh paths."""
    folder = os.path.join(pybullet_data.getDataPath(), "xarm")
    with open(os.path.join(folder, "xarm6_robot.urdf")) as f:
        text = f.read()
    return replace_inertials(absolute_mesh_paths(text, folder), HT_BR2_INERTIALS)


PROFILE = RobotProfile(
    name="xarm6",
    env_name="XArm6",
    urdf=xarm6_urdf,
    joint_names=tuple(f"joint{i}" for i in range(1, 7)),
    torque_limits_nm=(50.0, 50.0, 32.0, 32.0, 32.0, 20.0),
    joint_lower_rad=(-_TWO_PI, -2.059, -3.927, -_TWO_PI, -1.69297, -_TWO_PI),
    joint_upper_rad=(_TWO_PI, 2.0944, 0.19198, _TWO_PI, 3.14159265359, _TWO_PI),
    # Tool pointing down, flange at (0.378, 0, 0.421) m; every joint ≥ 1.09 rad from a limit.
    home_q_rad=(0.0, -0.35, -0.9, 0.0, 1.25, 0.0),
    path_amplitude_rad=(0.4, 0.3, 0.3, 0.4, 0.3, 0.4),
    path_period_s=8.0,
    ee_link="link6",
    circle=EECircle(center_m=(0.38, 0.0, 0.42), radius_m=0.08, normal=(1.0, 0.0, 0.0)),
    disturbance_scales=DisturbanceScales(
        impulse_j=0.5,
        push_n=20.0,
        payload_kg=1.0,
        mismatch_links=tuple(f"link{i}" for i in range(1, 7)),
    ),
    default_control_hz=500.0,
    controller_gains={
        "passivity": {"omega": 20.0, "omega_s": 20.0, "rho": 10.0, "lam": 2.0, "m_floor": 0.1},
        # bench/baseline_gain_study.py: the largest ω of the sweep with no clipped torque
        # from rest 0.1 rad off the path (ω = 28 clips computed torque's, 20 the others').
        "computed_torque": {"omega": 20.0},
        "computed_torque_observer": {"omega": 20.0},
        "computed_torque_path": {"omega": 20.0},
        "pd_gravity": {"omega": 14.0},
        "pid_gravity": {"omega": 14.0},
        "slotine_li": {"omega": 14.0},
        "adaptive_slotine_li": {"omega": 14.0},
    },
    convergence_target_s=30.0,
    camera_target_m=(0.2, 0.0, 0.35),
    camera_distance_m=1.3,
    source="pybullet_data xarm/xarm6_robot.urdf with UFactory xarm6_type6_HT_BR2 inertials; "
    "torque limits: UFactory URDF effort values",
)
