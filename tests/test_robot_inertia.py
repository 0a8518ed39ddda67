"""Link inertials of every robot the package ships, and the Panda against franka_ros.

1. No link that a joint moves carries rotational inertia without mass: a massless frame
   with a placeholder tensor (pybullet_data's Panda gives ``panda_link8`` and
   ``panda_grasptarget`` 0.1 kg·m² each) adds phantom inertia to the joint it rides on.
   Checked on the URDF the package loads, on the body PyBullet builds from it (after the
   package's loader) and on Pinocchio's model — and each check is shown to catch the
   pybullet_data original.
2. The shipped Panda's M(q) and g(q) (Pinocchio and PyBullet) equal those of an
   independent numpy model written here from franka_ros ``franka_description`` (the
   inertials of ``robots/common/inertial.yaml``, the joint origins of
   ``robots/common/franka_arm.xacro``, the hand mount of ``franka_robot.xacro`` and the
   finger mount of ``franka_hand.xacro``).
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from typing import NamedTuple

import numpy as np
import pybullet as p
import pybullet_data
import pytest

from ptrack_gym.robots import ROBOTS, BulletModel, PinocchioModel
from ptrack_gym.sim import BulletSim

RAW_PANDA = os.path.join(pybullet_data.getDataPath(), "franka_panda", "panda.urdf")


# -- URDF parsing (xml.etree only) --------------------------------------------------------


def rotation(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF's fixed-axis roll-pitch-yaw: R = Rz(y) Ry(p) Rx(r), shape (3, 3)."""
    (cr, sr), (cp, sp), (cy, sy) = ((math.cos(a), math.sin(a)) for a in rpy)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def transform(xyz: tuple[float, ...], rpy: tuple[float, ...]) -> np.ndarray:
    """The homogeneous transform (4, 4) of a URDF ``<origin>``."""
    out = np.eye(4)
    out[:3, :3] = rotation(rpy)  # type: ignore[arg-type]
    out[:3, 3] = xyz
    return out


class LinkInertial(NamedTuple):
    """A URDF link's inertial: mass (kg), centre of mass (m) and inertia tensor about it
    (kg·m², (3, 3)), both in the link frame."""

    mass_kg: float
    com_m: np.ndarray
    tensor_kgm2: np.ndarray


def _vector(element: ET.Element | None, name: str) -> tuple[float, ...]:
    text = element.get(name, "0 0 0") if element is not None else "0 0 0"
    return tuple(float(v) for v in text.split())


def urdf_inertials(root: ET.Element) -> dict[str, LinkInertial]:
    """Every link's inertial, the tensor rotated into the link frame (R I Rᵀ); a link
    without ``<inertial>`` has URDF's default, no mass and no inertia."""
    out = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            out[link.get("name")] = LinkInertial(0.0, np.zeros(3), np.zeros((3, 3)))
            continue
        origin = inertial.find("origin")
        t = inertial.find("inertia")
        ixx, ixy, ixz, iyy, iyz, izz = (
            float(t.get(k, "0")) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        )
        tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        rot = rotation(_vector(origin, "rpy"))  # type: ignore[arg-type]
        out[link.get("name")] = LinkInertial(
            float(inertial.find("mass").get("value")),
            np.array(_vector(origin, "xyz")),
            rot @ tensor @ rot.T,
        )
    return out


def moving_links(root: ET.Element) -> list[str]:
    """Links that a joint moves: below a non-fixed joint, however many fixed joints down
    (everything downstream of the first movable joint)."""
    parent_joint = {j.find("child").get("link"): j for j in root.findall("joint")}

    def moves(name: str) -> bool:
        while name in parent_joint:
            joint = parent_joint[name]
            if joint.get("type") != "fixed":
                return True
            name = joint.find("parent").get("link")
        return False

    return [link.get("name") for link in root.findall("link") if moves(link.get("name"))]


def urdf_massless_with_inertia(urdf_path: str) -> list[str]:
    """Moving links of the URDF with zero mass and a non-zero inertia tensor."""
    root = ET.parse(urdf_path).getroot()
    inertials = urdf_inertials(root)
    return [
        name
        for name in moving_links(root)
        if inertials[name].mass_kg == 0.0 and np.any(inertials[name].tensor_kgm2 != 0.0)
    ]


def bullet_massless_with_inertia(sim: BulletSim, body_id: int) -> list[str]:
    """Links of a PyBullet body (the fixed base excluded: every other link of a fixed-base
    arm moves) whose mass is 0 and local inertia diagonal is not."""
    out = []
    for j in range(p.getNumJoints(body_id, physicsClientId=sim.client_id)):
        mass, _, diagonal = p.getDynamicsInfo(body_id, j, physicsClientId=sim.client_id)[:3]
        if mass == 0.0 and any(diagonal):
            out.append(p.getJointInfo(body_id, j, physicsClientId=sim.client_id)[12].decode())
    return out


def pinocchio_phantom_inertia(urdf_path: str) -> dict[str, float]:
    """Per joint of Pinocchio's model of the URDF: max |I_pin − I_links| over the entries of
    the 6×6 spatial inertia, I_links the sum of the joint's links' URDF inertials placed
    in the joint frame with the rotational inertia of every massless link left out. Zero
    everywhere iff Pinocchio's bodies are the URDF's links and no massless link adds
    inertia (Pinocchio merges fixed-joint links into their joint's body, so a placeholder
    tensor would hide inside a body that has mass)."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(urdf_path)
    inertials = urdf_inertials(ET.parse(urdf_path).getroot())
    expected = [pin.Inertia.Zero() for _ in range(model.njoints)]
    for frame in model.frames:
        if frame.type != pin.FrameType.BODY or frame.parentJoint == 0:
            continue
        link = inertials[frame.name]
        tensor = link.tensor_kgm2 if link.mass_kg > 0.0 else np.zeros((3, 3))
        placed = frame.placement.act(pin.Inertia(link.mass_kg, link.com_m, tensor))
        expected[frame.parentJoint] = expected[frame.parentJoint] + placed
    return {
        model.names[j]: float(np.max(np.abs(model.inertias[j].matrix() - expected[j].matrix())))
        for j in range(1, model.njoints)
    }


# -- 1. no movable link with inertia but no mass ------------------------------------------


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_no_moving_link_of_the_urdf_has_inertia_without_mass(robot: str) -> None:
    profile = ROBOTS[robot]
    root = ET.parse(profile.urdf_path).getroot()
    assert len(moving_links(root)) >= profile.n
    assert urdf_massless_with_inertia(profile.urdf_path) == []


def test_the_urdf_check_finds_pybullet_datas_panda_placeholders() -> None:
    """The check is not vacuous: pybullet_data's Panda, which the package rewrites, fails
    it on exactly its two massless frames."""
    assert urdf_massless_with_inertia(RAW_PANDA) == ["panda_link8", "panda_grasptarget"]


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_pybullet_loads_the_urdf_inertials_and_no_massless_inertia(robot: str) -> None:
    """After the package's loader (``BulletSim.load_arm``: inertia from the file, damping
    zeroed), every link's mass is the URDF's and its local inertia diagonal the principal
    moments of the URDF's tensor — PyBullet patched nothing (it gives a link with no
    ``<inertial>`` 1 kg and 1 kg·m², and zeroes an unphysical tensor) — and no massless
    link has inertia."""
    profile = ROBOTS[robot]
    inertials = urdf_inertials(ET.parse(profile.urdf_path).getroot())
    with BulletSim() as sim:
        arm = sim.load_arm(profile.urdf_path, profile.joint_names, profile.torque_limits_nm)
        assert bullet_massless_with_inertia(sim, arm.body_id) == []
        for name in arm.link_names:
            mass, _, diagonal = p.getDynamicsInfo(
                arm.body_id, arm.link_index(name), physicsClientId=sim.client_id
            )[:3]
            urdf = inertials[name]
            assert mass == pytest.approx(urdf.mass_kg, rel=1e-12, abs=0.0), name
            moments = np.linalg.eigvalsh(urdf.tensor_kgm2)
            np.testing.assert_allclose(np.sort(diagonal), moments, rtol=1e-9, atol=1e-15)


def test_pybullet_keeps_a_massless_links_placeholder_inertia() -> None:
    """The PyBullet check is not vacuous: PyBullet keeps pybullet_data's 0.1 kg·m² on the
    Panda's massless frames (it does not drop the inertia of a massless link)."""
    with BulletSim() as sim:
        body = p.loadURDF(
            RAW_PANDA, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=sim.client_id,
        )  # fmt: skip
        assert bullet_massless_with_inertia(sim, body) == ["panda_link8", "panda_grasptarget"]


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_pinocchio_bodies_are_the_urdf_links_with_no_massless_inertia(robot: str) -> None:
    import pinocchio as pin

    model = pin.buildModelFromUrdf(ROBOTS[robot].urdf_path)
    for j in range(1, model.njoints):
        body = model.inertias[j]
        assert body.mass > 0.0 or not np.any(body.inertia), model.names[j]
    phantom = pinocchio_phantom_inertia(ROBOTS[robot].urdf_path)
    assert max(phantom.values()) < 1e-12, phantom


def test_the_pinocchio_check_finds_pybullet_datas_panda_placeholders() -> None:
    """The Pinocchio check is not vacuous: on pybullet_data's Panda the placeholders of
    panda_link8 and panda_grasptarget (0.1 kg·m² each, on joint 7's body) show as 0.2."""
    phantom = pinocchio_phantom_inertia(RAW_PANDA)
    assert phantom["panda_joint7"] == pytest.approx(0.2, abs=1e-12)
    assert max(v for k, v in phantom.items() if k != "panda_joint7") < 1e-12


# -- 2. the Panda against franka_ros --------------------------------------------------------

#: franka_ros ``franka_description/robots/common/inertial.yaml`` (frankaemika/franka_ros,
#: commit b2a62ff), in the file's order: mass (kg), origin xyz (m), inertia xx, yy, zz,
#: xy, xz, yz (kg·m²). Not official values: the identification of Gaz et al., IEEE RA-L
#: 2019. link0 is left out: the base is fixed.
FRANKA_ROS_YAML: dict[str, tuple[float, tuple[float, ...], tuple[float, ...]]] = {
    "panda_link1": (4.970684, (0.003875, 0.002081, -0.04762),
                    (0.70337, 0.70661, 0.0091170, -0.00013900, 0.0067720, 0.019169)),
    "panda_link2": (0.646926, (-0.003141, -0.02872, 0.003495),
                    (0.0079620, 2.8110e-02, 2.5995e-02, -3.9250e-3, 1.0254e-02, 7.0400e-04)),
    "panda_link3": (3.228604, (2.7518e-02, 3.9252e-02, -6.6502e-02),
                    (3.7242e-02, 3.6155e-02, 1.0830e-02, -4.7610e-03, -1.1396e-02,
                     -1.2805e-02)),
    "panda_link4": (3.587895, (-5.317e-02, 1.04419e-01, 2.7454e-02),
                    (2.5853e-02, 1.9552e-02, 2.8323e-02, 7.7960e-03, -1.3320e-03, 8.6410e-03)),
    "panda_link5": (1.225946, (-1.1953e-02, 4.1065e-02, -3.8437e-02),
                    (3.5549e-02, 2.9474e-02, 8.6270e-03, -2.1170e-03, -4.0370e-03, 2.2900e-04)),
    "panda_link6": (1.666555, (6.0149e-02, -1.4117e-02, -1.0517e-02),
                    (1.9640e-03, 4.3540e-03, 5.4330e-03, 1.0900e-04, -1.1580e-03, 3.4100e-04)),
    "panda_link7": (7.35522e-01, (1.0517e-02, -4.252e-03, 6.1597e-02),
                    (1.2516e-02, 1.0027e-02, 4.8150e-03, -4.2800e-04, -1.1960e-03,
                     -7.4100e-04)),
    "panda_hand": (0.73, (-0.01, 0.0, 0.03), (0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0)),
    "panda_leftfinger": (0.015, (0.0, 0.0, 0.0),
                         (2.3749999999999997e-06, 2.3749999999999997e-06, 7.5e-07, 0.0, 0.0,
                          0.0)),
    "panda_rightfinger": (0.015, (0.0, 0.0, 0.0),
                          (2.3749999999999997e-06, 2.3749999999999997e-06, 7.5e-07, 0.0, 0.0,
                           0.0)),
}  # fmt: skip

_HALF_PI = math.pi / 2.0
#: franka_ros ``franka_arm.xacro``: origin (xyz, rpy) of panda_joint1 … panda_joint7, each
#: turning about its own z axis.
FRANKA_ROS_JOINTS = (
    ((0.0, 0.0, 0.333), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (-_HALF_PI, 0.0, 0.0)),
    ((0.0, -0.316, 0.0), (_HALF_PI, 0.0, 0.0)),
    ((0.0825, 0.0, 0.0), (_HALF_PI, 0.0, 0.0)),
    ((-0.0825, 0.384, 0.0), (-_HALF_PI, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (_HALF_PI, 0.0, 0.0)),
    ((0.088, 0.0, 0.0), (_HALF_PI, 0.0, 0.0)),
)
#: Frames rigidly on link7 (transform from link7's frame): panda_joint8 puts link8 0.107 m
#: along z (``franka_arm.xacro``); the hand sits on link8 yawed by −π/4
#: (``franka_robot.xacro``); both fingers 0.0584 m along the hand's z, closed
#: (``franka_hand.xacro``; the shipped model locks the finger joints at 0).
_LINK8 = transform((0.0, 0.0, 0.107), (0.0, 0.0, 0.0))
_HAND = _LINK8 @ transform((0.0, 0.0, 0.0), (0.0, 0.0, -math.pi / 4.0))
_FINGER = _HAND @ transform((0.0, 0.0, 0.0584), (0.0, 0.0, 0.0))
_ON_LINK7 = {
    "panda_link7": np.eye(4), "panda_link8": _LINK8, "panda_grasptarget": _HAND,
    "panda_hand": _HAND, "panda_leftfinger": _FINGER, "panda_rightfinger": _FINGER,
}  # fmt: skip


def _yaml_inertial(name: str) -> LinkInertial:
    mass, com, (xx, yy, zz, xy, xz, yz) = FRANKA_ROS_YAML[name]
    tensor = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return LinkInertial(mass, np.array(com), tensor)


class FrankaRosPanda:
    """M(q) and g(q) of the Panda with its hand (fingers closed), from franka_ros' numbers
    alone: forward kinematics of :data:`FRANKA_ROS_JOINTS` and, per body b (centre of mass
    p_b, orientation R_b, mass m_b, inertia I_b about the centre of mass in its frame),

    .. math::

        M(q) = \\sum_b m_b J_{v,b}^T J_{v,b} + J_{\\omega,b}^T R_b I_b R_b^T J_{\\omega,b},
        \\qquad g(q) = \\sum_b m_b\\, g_0\\, J_{v,b}^T e_z,

    column k of J_{v,b} being z_k × (p_b − o_k) and of J_{ω,b} z_k for the joints k
    below b (z_k, o_k: axis and origin of joint k in the world).

    Args:
        extra: bodies added on link7, name → inertial (the placeholders' effect).
        gravity_mps2: g₀ (m/s²), along −z.
    """

    def __init__(
        self, extra: dict[str, LinkInertial] | None = None, gravity_mps2: float = 9.81
    ) -> None:
        self.gravity_mps2 = gravity_mps2
        self.bodies = [  # (joint index the body rides on, transform from that link, inertial)
            (i, np.eye(4), _yaml_inertial(f"panda_link{i + 1}")) for i in range(6)
        ]
        on_link7 = {name: _yaml_inertial(name) for name in _ON_LINK7 if name in FRANKA_ROS_YAML}
        on_link7.update(extra or {})
        self.bodies += [(6, _ON_LINK7[name], block) for name, block in on_link7.items()]

    def _jacobians(self, q: np.ndarray):  # (m, Jv (3, 7), Jw (3, 7), R I Rᵀ) per body
        frames, pose = [], np.eye(4)
        for (xyz, rpy), qk in zip(FRANKA_ROS_JOINTS, q, strict=True):
            pose = pose @ transform(xyz, rpy) @ transform((0.0, 0.0, 0.0), (0.0, 0.0, qk))
            frames.append(pose)
        axes = [f[:3, 2] for f in frames]
        origins = [f[:3, 3] for f in frames]
        for i, offset, (mass, com, tensor) in self.bodies:
            body = frames[i] @ offset
            com_world = body[:3, :3] @ com + body[:3, 3]
            jv, jw = np.zeros((3, 7)), np.zeros((3, 7))
            for k in range(i + 1):
                jv[:, k] = np.cross(axes[k], com_world - origins[k])
                jw[:, k] = axes[k]
            yield mass, jv, jw, body[:3, :3] @ tensor @ body[:3, :3].T

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q) (kg·m²), (7, 7)."""
        return sum(m * jv.T @ jv + jw.T @ rot_i @ jw for m, jv, jw, rot_i in self._jacobians(q))

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """g(q) (N·m), (7,)."""
        return sum(m * self.gravity_mps2 * jv[2] for m, jv, _, _ in self._jacobians(q))


#: Tolerances of the comparison. pybullet_data writes π/2 as 1.57079632679 (5e-12 rad off),
#: so M and g agree to 1.6e-11 kg·m² and 1.4e-10 N·m (with that rounding in
#: :data:`FRANKA_ROS_JOINTS` too: 2e-15 and 1e-14); the placeholders' error is 0.2 kg·m².
M_ATOL_KGM2 = 1e-9
G_ATOL_NM = 1e-8


def _panda_poses() -> list[np.ndarray]:
    lower, upper = ROBOTS["panda"].limits()
    rng = np.random.default_rng(7)
    return [np.zeros(7), ROBOTS["panda"].home(), *rng.uniform(lower, upper, size=(8, 7))]


def test_panda_inertials_are_franka_ros() -> None:
    """Every inertial of the shipped Panda URDF is franka_ros': mass, centre of mass and
    tensor (the URDF writes it in principal axes, R diag Rᵀ: back to within 5e-15 kg·m²),
    link by link; the two frames have none."""
    inertials = urdf_inertials(ET.parse(ROBOTS["panda"].urdf_path).getroot())
    for name in FRANKA_ROS_YAML:
        shipped, franka = inertials[name], _yaml_inertial(name)
        assert shipped.mass_kg == franka.mass_kg, name
        np.testing.assert_array_equal(shipped.com_m, franka.com_m, err_msg=name)
        np.testing.assert_allclose(
            shipped.tensor_kgm2, franka.tensor_kgm2, rtol=0, atol=1e-13, err_msg=name
        )
    for frame in ("panda_link8", "panda_grasptarget"):
        assert inertials[frame].mass_kg == 0.0
        assert not np.any(inertials[frame].tensor_kgm2)


def test_panda_mass_matrix_and_gravity_are_franka_ros() -> None:
    """The package's Panda (Pinocchio, and PyBullet's ``calculateMassMatrix`` and inverse
    dynamics) against :class:`FrankaRosPanda` at q = 0, home and 8 random poses within the
    joint limits: |ΔM| ≤ 1e-9 kg·m², |Δg| ≤ 1e-8 N·m (measured 1.6e-11 and 1.4e-10, both
    models). The old placeholder frames (0.1 kg·m² on panda_link8 and panda_grasptarget)
    miss by 0.2 kg·m² (2e8 tolerances): M's wrist diagonal at q = 0 becomes 0.24, 0.25,
    0.21 kg·m² instead of 0.040, 0.053, 0.0067."""
    franka = FrankaRosPanda()
    pin_model, bullet = PinocchioModel(ROBOTS["panda"]), BulletModel(ROBOTS["panda"])
    try:
        for q in _panda_poses():
            m_ref, g_ref = franka.mass_matrix(q), franka.gravity(q)
            for model in (pin_model, bullet):
                np.testing.assert_allclose(model.mass_matrix(q), m_ref, rtol=0, atol=M_ATOL_KGM2)
                np.testing.assert_allclose(model.gravity(q), g_ref, rtol=0, atol=G_ATOL_NM)
    finally:
        bullet.close()
    # The comparison fails on the placeholders (massless and isotropic, so where on link7
    # they sit does not matter).
    placeholder = LinkInertial(0.0, np.zeros(3), 0.1 * np.eye(3))
    old = FrankaRosPanda(extra={"panda_link8": placeholder, "panda_grasptarget": placeholder})
    q0 = np.zeros(7)
    wrist = np.diag(old.mass_matrix(q0))[4:]
    np.testing.assert_allclose(wrist, [0.2402, 0.2530, 0.2067], atol=1e-4)
    np.testing.assert_allclose(np.diag(franka.mass_matrix(q0))[4:], wrist - 0.2, atol=1e-12)
    assert np.max(np.abs(old.mass_matrix(q0) - franka.mass_matrix(q0))) > 1e7 * M_ATOL_KGM2
