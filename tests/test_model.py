"""Dynamics models: both against the closed-form two-link arm, the q-keyed cache, plant
independence and bad input. The per-robot identities (Pinocchio = PyBullet, M SPD, g = ∇U,
Ṁ − 2C skew) are in ``test_robot_battery.py``."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from ptrack_gym.robots import ROBOTS, BulletModel, PinocchioModel, robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel
from ptrack_gym.sim import BulletSim


def test_both_models_match_the_closed_form_two_link_arm() -> None:
    analytic = TwoLinkAnalyticModel()
    profile = robot_profile("two_link")
    bullet = BulletModel(profile)
    rng = np.random.default_rng(0)
    for model in (PinocchioModel(profile), bullet):
        for _ in range(50):
            q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(0, 2, 2), rng.normal(0, 5, 2)
            np.testing.assert_allclose(model.mass_matrix(q), analytic.mass_matrix(q), atol=1e-12)
            np.testing.assert_allclose(model.gravity(q), analytic.gravity(q), atol=1e-12)
            np.testing.assert_allclose(model.coriolis(q, qd), analytic.coriolis(q, qd), atol=1e-12)
            np.testing.assert_allclose(
                model.inverse_dynamics(q, qd, qdd),
                analytic.inverse_dynamics(q, qd, qdd),
                atol=1e-11,
            )
            # Same zero of potential: both arms horizontal at the base height.
            assert model.potential(q) == pytest.approx(analytic.potential(q), abs=1e-12)
    pin = PinocchioModel(profile)
    for _ in range(20):
        q, qd = rng.uniform(-3, 3, 2), rng.normal(0, 2, 2)
        np.testing.assert_allclose(
            pin.coriolis_matrix(q, qd), analytic.coriolis_matrix(q, qd), atol=1e-12
        )
    bullet.close()


def test_cached_mass_matrix_and_potential_follow_q() -> None:
    """The one-entry cache keyed on q: the same q gives the same (read-only) array, another
    q (e.g. a noisy measurement of it) a fresh evaluation, equal to an uncached model's."""
    profile = robot_profile("iiwa")
    cached, fresh = PinocchioModel(profile), PinocchioModel(profile)
    q = profile.home()
    m1 = cached.mass_matrix(q)
    assert cached.mass_matrix(q.copy()) is m1
    assert not m1.flags.writeable
    noisy = q + 1e-9
    assert cached.mass_matrix(noisy) is not m1
    np.testing.assert_array_equal(cached.mass_matrix(noisy), fresh.mass_matrix(noisy))
    np.testing.assert_array_equal(cached.mass_matrix(q), fresh.mass_matrix(q))
    assert cached.potential(noisy) == fresh.potential(noisy) != cached.potential(q)


def test_models_do_not_see_a_perturbed_plant() -> None:
    """Neither model shares the simulated body: adding mass to it changes nothing."""
    profile = robot_profile("two_link")
    models = [BulletModel(profile), PinocchioModel(profile)]
    q = np.array([0.3, -0.4])
    before = [m.gravity(q).copy() for m in models]
    with BulletSim() as sim:
        arm = sim.load_arm(profile.urdf_path, profile.joint_names, profile.torque_limits_nm)
        p.changeDynamics(
            arm.body_id, arm.link_index("link2"), mass=5.0, physicsClientId=sim.client_id
        )
    for model, g in zip(models, before, strict=True):
        np.testing.assert_array_equal(model.gravity(q), g)
    models[0].close()


def test_models_reject_bad_inputs() -> None:
    bullet = BulletModel(robot_profile("two_link"))
    with pytest.raises(ValueError, match="shape"):
        bullet.mass_matrix(np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        bullet.gravity(np.array([0.0, np.nan]))
    bullet.close()
    pin = PinocchioModel(robot_profile("two_link"))
    with pytest.raises(ValueError, match="wrong argument size"):
        pin.mass_matrix(np.zeros(3))
    with pytest.raises(ValueError, match="wrong argument size"):
        pin.inverse_dynamics(np.zeros(2), np.zeros(3), np.zeros(2))


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_no_link_carries_inertia_without_mass(robot: str) -> None:
    """Every movable link of every robot's URDF (as loaded) that has no mass has no
    rotational inertia either: a massless frame with a placeholder inertia (pybullet_data's
    Panda gave panda_link8 and panda_grasptarget 0.1 kg·m² each) adds phantom inertia to
    the joint it rides on."""
    import xml.etree.ElementTree as ET

    root = ET.parse(ROBOTS[robot].urdf_path).getroot()
    parent = {j.find("child").get("link"): j for j in root.findall("joint")}

    def movable(name: str) -> bool:  # below a joint that moves, however far up
        while name in parent:
            joint = parent[name]
            if joint.get("type") != "fixed":
                return True
            name = joint.find("parent").get("link")
        return False

    links = [link for link in root.findall("link") if movable(link.get("name"))]
    assert len(links) >= ROBOTS[robot].n
    for link in links:
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = float(inertial.find("mass").get("value"))
        tensor = inertial.find("inertia")
        moments = [float(tensor.get(k, "0")) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")]
        if mass == 0.0:
            assert not any(moments), f"{robot}: link {link.get('name')} has inertia {moments}"


def test_panda_wrist_inertia_is_franka_ros_not_a_placeholder() -> None:
    """M_77 at q = 0 by hand from the franka_ros values: joint 7 turns link7, the hand and the
    fingers about link7's z axis, and the hand (yawed −45° about that axis, 0.107 m along it)
    and the fingers (on it) keep their z moments, so M_77 = Σ (I_zz + m (x² + y²)) over the
    three in link7's frame — about 0.0067 kg·m², not the 0.21 kg·m² the placeholder links
    added."""
    from ptrack_gym.robots.panda import FRANKA_ROS_INERTIALS as F

    def about_axis(name: str) -> float:
        block = F[name]
        x, y, _ = block.com_m
        return block.inertia_kgm2[5] + block.mass_kg * (x * x + y * y)

    expected = (
        about_axis("panda_link7") + about_axis("panda_hand")
        + F["panda_leftfinger"].inertia_kgm2[5] + F["panda_rightfinger"].inertia_kgm2[5]
    )  # fmt: skip
    assert expected == pytest.approx(0.0067, abs=2e-4)
    for model in (PinocchioModel(ROBOTS["panda"]), BulletModel(ROBOTS["panda"])):
        assert model.mass_matrix(np.zeros(7))[6, 6] == pytest.approx(expected, rel=1e-9)
