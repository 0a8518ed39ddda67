"""Dynamics models: both against the closed-form two-link arm, the q-keyed cache, plant
independence and bad input. The per-robot identities (Pinocchio = PyBullet, M SPD, g = ∇U,
Ṁ − 2C skew) are in ``test_robot_battery.py``."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from ptrack_gym.robots import BulletModel, PinocchioModel, robot_profile
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
