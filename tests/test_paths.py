"""Reference paths: derivatives, periodicity, rejection of out-of-limit paths, seeded and
admissible random paths, the IK circle, and the nearest-point search (model-free)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from agents.passivity_tables import PassivityTables
from ptrack_gym.errors import InvalidPathError
from ptrack_gym.paths import (
    MIN_SPEED_FRACTION,
    MultiSinePath,
    PathProjector,
    SplinePath,
    check_joint_limits,
    default_path,
    ee_circle_path,
    min_speed_fraction,
    random_multisine,
)
from ptrack_gym.robots import ROBOTS, EECircle, PinocchioModel, robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot_path(request):
    profile = robot_profile(request.param)
    path = default_path(profile)
    yield profile, path, PathProjector(path)


def fd(f, s, h=1e-5):
    return (f(s + h) - f(s - h)) / (2 * h)


def test_multisine_derivatives_and_period() -> None:
    path = default_path(robot_profile("iiwa"))
    for s in np.linspace(0.0, 8.0, 13):
        q, qd, qdd = path.evaluate(s)
        np.testing.assert_allclose(qd, fd(lambda x: path.evaluate(x)[0], s), atol=1e-8)
        np.testing.assert_allclose(qdd, fd(lambda x: path.evaluate(x)[1], s), atol=1e-8)
        np.testing.assert_allclose(path.evaluate(s + path.period_s)[0], q, atol=1e-12)
    # Vectorised evaluation equals the scalar one.
    ss = np.array([0.1, 2.3, 7.9])
    batch = path.evaluate(ss)
    for i, s in enumerate(ss):
        for a, b in zip(batch, path.evaluate(s), strict=True):
            np.testing.assert_allclose(a[i], b, atol=1e-14)


def test_spline_path_is_periodic_and_c2_at_the_seam() -> None:
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    path = SplinePath(np.column_stack([np.sin(t), np.cos(2 * t)]), period_s=3.0)
    for k in range(3):
        left, right = path.evaluate(3.0 - 1e-9)[k], path.evaluate(1e-9)[k]
        np.testing.assert_allclose(left, right, atol=1e-6)
    # It interpolates its samples.
    np.testing.assert_allclose(path.evaluate(3.0 * 5 / 64)[0], [np.sin(t[5]), np.cos(2 * t[5])])


def test_path_outside_joint_limits_is_rejected_naming_joint() -> None:
    spec = robot_profile("two_link")
    amp = np.array([[0.1, 3.0]])
    path = MultiSinePath(np.array(spec.home_q_rad), amp, np.zeros((1, 2)), period_s=4.0)
    with pytest.raises(InvalidPathError, match="joint 1"):
        check_joint_limits(path, *spec.limits())
    check_joint_limits(default_path(spec), *spec.limits())  # the default is fine


def test_bad_path_arguments() -> None:
    with pytest.raises(InvalidPathError):
        MultiSinePath(np.zeros(2), np.ones((1, 3)), np.ones((1, 3)), 1.0)
    with pytest.raises(InvalidPathError):
        MultiSinePath(np.zeros(2), np.ones((1, 2)), np.ones((1, 2)), -1.0)
    with pytest.raises(InvalidPathError):
        SplinePath(np.zeros((2, 2)), 1.0)


def test_random_paths_are_seeded() -> None:
    spec = robot_profile("panda")
    a = random_multisine(spec, np.random.default_rng(7))
    b = random_multisine(spec, np.random.default_rng(7))
    c = random_multisine(spec, np.random.default_rng(8))
    np.testing.assert_array_equal(a.evaluate(1.3)[0], b.evaluate(1.3)[0])
    assert not np.array_equal(a.evaluate(1.3)[0], c.evaluate(1.3)[0])


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_random_paths_are_admissible_on_every_robot(robot: str) -> None:
    """Every seed gives a path inside the limits whose M_r never falls below 5% of its mean
    (the two-link's raw draws are nearly stationary for most seeds), so the passivity
    controller accepts every one."""
    spec = robot_profile(robot)
    model = PinocchioModel(spec)
    for seed in range(12):
        path = random_multisine(spec, np.random.default_rng(seed), metric=model.mass_matrix)
        check_joint_limits(path, *spec.limits())
        assert min_speed_fraction(path, model.mass_matrix) >= MIN_SPEED_FRACTION
        PassivityTables(path, model, grid_size=256)


def test_random_path_sampler_gives_up_with_a_clear_error() -> None:
    spec = robot_profile("two_link")
    with pytest.raises(InvalidPathError, match="no admissible random path"):
        # One harmonic, every joint in phase: always stationary twice per period.
        random_multisine(spec, np.random.default_rng(0), harmonics=1, max_draws=0)


def test_ee_circle_path_follows_the_circle() -> None:
    spec = robot_profile("two_link")
    center, radius = np.array([0.5, 0.0, -0.3]), 0.15
    path = ee_circle_path(
        spec, EECircle(center_m=(0.5, 0.0, -0.3), radius_m=radius, normal=(0.0, 1.0, 0.0)), 128
    )
    fk = TwoLinkAnalyticModel()
    s = np.linspace(0.0, path.period_s, 301)
    q = path.evaluate(s)[0]
    tip = np.array([fk.ee_position(qi) for qi in q])  # (x, z)
    r = np.linalg.norm(tip - center[[0, 2]], axis=1)
    # Samples are exact (IK to 1e-10 m); between them the cubic spline deviates O(h⁴).
    np.testing.assert_allclose(r, radius, atol=2e-5)
    PassivityTables(path, TwoLinkAnalyticModel())  # non-stationary


def test_nearest_matches_brute_force_and_is_zero_on_the_path(robot_path) -> None:
    spec, path, projector = robot_path
    rng = np.random.default_rng(5)
    for scale in (0.0, 1e-5, 1e-2, 0.2):
        s_true = rng.uniform(0.0, path.period_s)
        q = path.evaluate(s_true)[0] + scale * rng.standard_normal(spec.n)
        near = projector.nearest(q)
        res = minimize_scalar(
            lambda x, q=q: float(np.linalg.norm(q - path.evaluate(x)[0])),
            bracket=(near.s - 0.01, near.s + 0.01),
            tol=1e-12,
        )
        # The reference minimiser is itself accurate to ~1e-12 only.
        assert abs(near.distance - res.fun) <= 1e-9 + 1e-6 * res.fun
        # The returned s is where the returned distance is attained.
        at_s = float(np.linalg.norm(q - path.evaluate(near.s)[0]))
        assert at_s == pytest.approx(near.distance, abs=1e-9, rel=1e-6)
        if scale == 0.0:
            assert near.distance < 1e-9
            assert min(abs(near.s - s_true), path.period_s - abs(near.s - s_true)) < 1e-6
