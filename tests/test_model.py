"""Dynamics models against independent computations: the closed-form two-link arm,
finite differences of the potential and of M(q), and the skew-symmetry power identity."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from ptrack_gym.robots import ROBOTS, BulletModel, TwoLinkAnalyticModel, make_robot, two_link
from ptrack_gym.sim import BulletSim


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot(request):
    spec = make_robot(request.param)
    model = BulletModel(spec)
    yield spec, model
    model.close()


def random_states(spec, rng, count=10):
    lo, hi = spec.limits()
    home = np.array(spec.home_q_rad)
    for _ in range(count):
        q = np.clip(home + rng.uniform(-0.5, 0.5, spec.n), lo + 0.05, hi - 0.05)
        yield q, rng.normal(0.0, 1.0, spec.n), rng.normal(0.0, 2.0, spec.n)


def test_two_link_bullet_model_matches_closed_form() -> None:
    analytic, bullet = TwoLinkAnalyticModel(), BulletModel(two_link())
    rng = np.random.default_rng(0)
    for _ in range(50):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(0, 2, 2), rng.normal(0, 5, 2)
        np.testing.assert_allclose(bullet.mass_matrix(q), analytic.mass_matrix(q), atol=1e-12)
        np.testing.assert_allclose(bullet.gravity(q), analytic.gravity(q), atol=1e-12)
        np.testing.assert_allclose(bullet.coriolis(q, qd), analytic.coriolis(q, qd), atol=1e-12)
        np.testing.assert_allclose(
            bullet.inverse_dynamics(q, qd, qdd), analytic.inverse_dynamics(q, qd, qdd), atol=1e-11
        )
        # Same zero of potential: both arms horizontal at the base height.
        assert bullet.potential(q) == pytest.approx(analytic.potential(q), abs=1e-12)
    bullet.close()


def test_mass_matrix_symmetric_positive_definite(robot) -> None:
    spec, model = robot
    for q, _, _ in random_states(spec, np.random.default_rng(1)):
        m = model.mass_matrix(q)
        np.testing.assert_allclose(m, m.T, atol=1e-14)
        assert np.linalg.eigvalsh(m).min() > 0.0


def test_gravity_is_gradient_of_potential(robot) -> None:
    spec, model = robot
    h = 1e-6
    for q, _, _ in random_states(spec, np.random.default_rng(2)):
        grad = np.array(
            [
                (model.potential(q + h * e) - model.potential(q - h * e)) / (2 * h)
                for e in np.eye(spec.n)
            ]
        )
        # Central differences: truncation O(h²) ~ 1e-12, rounding ~ |U|·1e-16/h ~ 1e-9.
        np.testing.assert_allclose(model.gravity(q), grad, atol=1e-7)


def test_power_identity_from_skew_symmetry(robot) -> None:
    """q̇ᵀ C(q, q̇) q̇ = ½ q̇ᵀ Ṁ q̇ (Ṁ − 2C skew-symmetric), Ṁ by central differences."""
    spec, model = robot
    h = 1e-6
    for q, qd, _ in random_states(spec, np.random.default_rng(3)):
        m_dot = (model.mass_matrix(q + h * qd) - model.mass_matrix(q - h * qd)) / (2 * h)
        lhs = qd @ model.coriolis(q, qd)
        assert lhs == pytest.approx(0.5 * qd @ m_dot @ qd, abs=1e-7)
        # C(q, q̇) q̇ is quadratic in q̇.
        np.testing.assert_allclose(model.coriolis(q, 2 * qd), 4 * model.coriolis(q, qd), atol=1e-10)


def test_inverse_dynamics_is_m_qdd_plus_bias(robot) -> None:
    spec, model = robot
    for q, qd, qdd in random_states(spec, np.random.default_rng(4)):
        expected = model.mass_matrix(q) @ qdd + model.coriolis(q, qd) + model.gravity(q)
        np.testing.assert_allclose(model.inverse_dynamics(q, qd, qdd), expected, atol=1e-9)


def test_model_does_not_see_a_perturbed_plant() -> None:
    """The model owns its own client: adding mass to the simulated body changes nothing."""
    spec = two_link()
    model = BulletModel(spec)
    q = np.array([0.3, -0.4])
    before = model.gravity(q).copy()
    with BulletSim() as sim:
        arm = sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)
        p.changeDynamics(
            arm.body_id, arm.link_index("link2"), mass=5.0, physicsClientId=sim.client_id
        )
    np.testing.assert_array_equal(model.gravity(q), before)
    model.close()


def test_model_rejects_bad_inputs() -> None:
    model = BulletModel(two_link())
    with pytest.raises(ValueError, match="shape"):
        model.mass_matrix(np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        model.gravity(np.array([0.0, np.nan]))
    model.close()
