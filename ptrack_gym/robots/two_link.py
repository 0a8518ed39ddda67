"""A planar two-link arm in the vertical x–z plane, and its closed-form dynamics.

Both joints turn about the world's −y axis, so joint angle 0 points a link along +x
(horizontal) and a positive angle lifts it towards +z (against gravity, which acts
along −z). With link lengths l1, l2, centre-of-mass distances lc1, lc2 from each
link's joint, masses m1, m2 and inertias I1, I2 about the centre of mass around the
joint axis, the textbook equations (Spong, Hutchinson & Vidyasagar, §7.3) are

.. math::

    M(q) = \\begin{bmatrix}
        m_1 l_{c1}^2 + m_2 (l_1^2 + l_{c2}^2 + 2 l_1 l_{c2} \\cos q_2) + I_1 + I_2 &
        m_2 (l_{c2}^2 + l_1 l_{c2} \\cos q_2) + I_2 \\\\
        \\cdot & m_2 l_{c2}^2 + I_2 \\end{bmatrix}

    C(q, \\dot q)\\dot q = h \\begin{bmatrix} -2\\dot q_1 \\dot q_2 - \\dot q_2^2 \\\\
        \\dot q_1^2 \\end{bmatrix}, \\quad h = m_2 l_1 l_{c2} \\sin q_2

    U(q) = g\\,(m_1 l_{c1} \\sin q_1 + m_2 (l_1 \\sin q_1 + l_{c2} \\sin(q_1 + q_2)))

The URDF written by :func:`two_link_urdf` uses exactly these parameters, so the
analytic model is an independent check of PyBullet's dynamics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ptrack_gym.robots.profile import DisturbanceScales, EECircle, FloatArray, RobotProfile


@dataclass(frozen=True)
class TwoLinkParams:
    """Physical parameters of the two-link arm (SI units)."""

    l1_m: float = 0.5
    l2_m: float = 0.5
    lc1_m: float = 0.25
    lc2_m: float = 0.25
    m1_kg: float = 2.0
    m2_kg: float = 1.0
    # Slender rods: I = m l² / 12 about the centre of mass, around the joint axis (kg·m²).
    i1_kgm2: float = 2.0 * 0.5**2 / 12.0
    i2_kgm2: float = 1.0 * 0.5**2 / 12.0
    # Small inertia about the rod's own long axis (kg·m²); irrelevant in the plane.
    i_axial_kgm2: float = 1e-4
    gravity_mps2: float = 9.81


def two_link_urdf(params: TwoLinkParams) -> str:
    """URDF text of the two-link arm with the given parameters."""

    def link(name: str, length: float, lc: float, m: float, inertia: float, rgba: str) -> str:
        return f"""
  <link name="{name}">
    <inertial>
      <origin xyz="{lc!r} 0 0" rpy="0 0 0"/>
      <mass value="{m!r}"/>
      <inertia ixx="{params.i_axial_kgm2!r}" ixy="0" ixz="0" iyy="{inertia!r}" iyz="0"
               izz="{inertia!r}"/>
    </inertial>
    <visual>
      <origin xyz="{length / 2!r} 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><cylinder radius="0.03" length="{length!r}"/></geometry>
      <material name="{name}_mat"><color rgba="{rgba}"/></material>
    </visual>
  </link>"""

    def joint(name: str, parent: str, child: str, x: float) -> str:
        return f"""
  <joint name="{name}" type="revolute">
    <parent link="{parent}"/>
    <child link="{child}"/>
    <origin xyz="{x!r} 0 0" rpy="0 0 0"/>
    <axis xyz="0 -1 0"/>
    <limit lower="-3.141592653589793" upper="3.141592653589793" effort="100" velocity="50"/>
  </joint>"""

    p = params
    return f"""<?xml version="1.0"?>
<robot name="two_link">
  <link name="base">
    <inertial>
      <mass value="1.0"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/>
    </inertial>
    <visual>
      <geometry><box size="0.1 0.1 0.1"/></geometry>
      <material name="base_mat"><color rgba="0.3 0.3 0.3 1"/></material>
    </visual>
  </link>{link("link1", p.l1_m, p.lc1_m, p.m1_kg, p.i1_kgm2, "0.2 0.4 0.8 1")}{
        link("link2", p.l2_m, p.lc2_m, p.m2_kg, p.i2_kgm2, "0.9 0.5 0.1 1")
    }{joint("joint1", "base", "link1", 0.0)}{joint("joint2", "link1", "link2", p.l1_m)}
  <link name="tip">
    <inertial>
      <mass value="0"/>
      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>
    </inertial>
  </link>
  <joint name="tip_joint" type="fixed">
    <parent link="link2"/>
    <child link="tip"/>
    <origin xyz="{p.l2_m!r} 0 0" rpy="0 0 0"/>
  </joint>
</robot>
"""


def _urdf() -> str:
    return two_link_urdf(TwoLinkParams())


#: The two-link arm with the default :class:`TwoLinkParams`. Torque limits (40, 20) N·m are
#: about 3× the worst-case gravity torques (12.3, 2.5) N·m.
PROFILE = RobotProfile(
    name="two_link",
    env_name="TwoLink",
    urdf=_urdf,
    joint_names=("joint1", "joint2"),
    torque_limits_nm=(40.0, 20.0),
    joint_lower_rad=(-np.pi, -np.pi),
    joint_upper_rad=(np.pi, np.pi),
    home_q_rad=(-0.6, 1.0),
    path_amplitude_rad=(0.5, 0.6),
    path_period_s=4.0,
    ee_link="tip",
    circle=EECircle(center_m=(0.5, 0.0, -0.3), radius_m=0.15, normal=(0.0, 1.0, 0.0)),
    disturbance_scales=DisturbanceScales(
        impulse_j=0.3, push_n=10.0, payload_kg=0.5, mismatch_links=("link1", "link2")
    ),
    default_control_hz=250.0,
    # Rates of the gain studies (docs/passivity_gain_study.md, docs/baselines.md).
    controller_gains={
        "passivity": {"omega": 20.0, "omega_s": 20.0, "rho": 10.0, "lam": 2.0, "m_floor": 0.1},
        "computed_torque": {"omega": 20.0},
        "computed_torque_observer": {"omega": 20.0},
        "computed_torque_path": {"omega": 20.0},
        "pd_gravity": {"omega": 20.0},
        "pid_gravity": {"omega": 20.0},
        "slotine_li": {"omega": 20.0},
        "adaptive_slotine_li": {"omega": 20.0},
    },
    convergence_target_s=20.0,
    camera_target_m=(0.3, 0.0, 0.0),
    camera_distance_m=1.4,
    source="our URDF (two_link_urdf) with the closed-form model TwoLinkAnalyticModel",
)


class TwoLinkAnalyticModel:
    """Closed-form dynamics of :func:`two_link` (see the module docstring).

    Implements the :class:`ptrack_gym.robots.model.RobotModel` protocol: an independent
    check of the Pinocchio and PyBullet models in the tests.
    """

    def __init__(self, params: TwoLinkParams | None = None) -> None:
        self.params = params or TwoLinkParams()
        self.n = 2

    def mass_matrix(self, q: FloatArray) -> FloatArray:
        """M(q) (kg·m²), shape (2, 2)."""
        p = self.params
        c2 = np.cos(q[1])
        m22 = p.m2_kg * p.lc2_m**2 + p.i2_kgm2
        m12 = p.m2_kg * (p.lc2_m**2 + p.l1_m * p.lc2_m * c2) + p.i2_kgm2
        m11 = (
            p.m1_kg * p.lc1_m**2
            + p.m2_kg * (p.l1_m**2 + p.lc2_m**2 + 2.0 * p.l1_m * p.lc2_m * c2)
            + p.i1_kgm2
            + p.i2_kgm2
        )
        return np.array([[m11, m12], [m12, m22]])

    def coriolis(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """C(q, q̇) q̇ (N·m), shape (2,)."""
        p = self.params
        h = p.m2_kg * p.l1_m * p.lc2_m * np.sin(q[1])
        return np.array([-h * (2.0 * qd[0] * qd[1] + qd[1] ** 2), h * qd[0] ** 2])

    def gravity(self, q: FloatArray) -> FloatArray:
        """g(q) = ∂U/∂q (N·m), shape (2,)."""
        p = self.params
        c1, c12 = np.cos(q[0]), np.cos(q[0] + q[1])
        g = p.gravity_mps2
        return np.array(
            [
                g * ((p.m1_kg * p.lc1_m + p.m2_kg * p.l1_m) * c1 + p.m2_kg * p.lc2_m * c12),
                g * p.m2_kg * p.lc2_m * c12,
            ]
        )

    def potential(self, q: FloatArray) -> float:
        """U(q) (J), zero when both links are horizontal at the base height."""
        p = self.params
        s1, s12 = np.sin(q[0]), np.sin(q[0] + q[1])
        return float(
            p.gravity_mps2 * (p.m1_kg * p.lc1_m * s1 + p.m2_kg * (p.l1_m * s1 + p.lc2_m * s12))
        )

    def inverse_dynamics(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """τ = M(q) q̈ + C(q, q̇) q̇ + g(q) (N·m)."""
        return self.mass_matrix(q) @ qdd + self.coriolis(q, qd) + self.gravity(q)

    def coriolis_matrix(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """The Christoffel Coriolis matrix C(q, q̇) (N·m·s/rad), shape (2, 2):
        [[−h q̇₂, −h (q̇₁ + q̇₂)], [h q̇₁, 0]], h = m₂ l₁ l_c2 sin q₂."""
        p = self.params
        h = p.m2_kg * p.l1_m * p.lc2_m * np.sin(q[1])
        return np.array([[-h * qd[1], -h * (qd[0] + qd[1])], [h * qd[0], 0.0]])

    def kinetic_energy(self, q: FloatArray, qd: FloatArray) -> float:
        """½ q̇ᵀ M(q) q̇ (J)."""
        return 0.5 * float(qd @ self.mass_matrix(q) @ qd)

    def ee_position(self, q: FloatArray) -> FloatArray:
        """Tip position (x, z) in the plane (m)."""
        p = self.params
        return np.array(
            [
                p.l1_m * np.cos(q[0]) + p.l2_m * np.cos(q[0] + q[1]),
                p.l1_m * np.sin(q[0]) + p.l2_m * np.sin(q[0] + q[1]),
            ]
        )
