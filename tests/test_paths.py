"""Reference paths and their tables: derivatives, periodicity, the exact identities of
CONTROL_LAW.md checked against finite differences, interpolation accuracy, rejection of
stationary or out-of-limit paths, seeded sampling, and the nearest-point search."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from ptrack_gym.errors import InvalidPathError
from ptrack_gym.paths import (
    MultiSinePath,
    PathTables,
    SplinePath,
    check_joint_limits,
    default_path,
    ee_circle_path,
    random_multisine,
)
from ptrack_gym.robots import ROBOTS, BulletModel, TwoLinkAnalyticModel, make_robot, two_link


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot_tables(request):
    spec = make_robot(request.param)
    model = BulletModel(spec)
    yield spec, model, PathTables(default_path(spec), model)
    model.close()


def fd(f, s, h=1e-5):
    return (f(s + h) - f(s - h)) / (2 * h)


def test_multisine_derivatives_and_period() -> None:
    path = default_path(make_robot("iiwa"))
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


def test_table_identities_match_finite_differences(robot_tables) -> None:
    """W_r' = −q_r'ᵀτ_r and M_r' = 2 q_r'ᵀ(τ_r − g) against central differences of
    W_r(s) = −U(q_r) − ½M_r and M_r(s) = q_r'ᵀ M(q_r) q_r' computed on line."""
    _, _, tables = robot_tables
    for s in np.linspace(0.0, tables.period_s, 9, endpoint=False) + 0.0123:
        pt = tables.exact(s)
        w_fd = fd(lambda x: tables.exact(x).w_r, s)
        m_fd = fd(lambda x: tables.exact(x).m_r, s)
        scale = max(abs(pt.w_r_d), abs(pt.m_r_d), 1.0)
        assert pt.w_r_d == pytest.approx(w_fd, abs=1e-6 * scale)
        assert pt.m_r_d == pytest.approx(m_fd, abs=1e-6 * scale)


def test_interpolated_tables_match_exact_values(robot_tables) -> None:
    _, _, tables = robot_tables
    rng = np.random.default_rng(0)
    for s in rng.uniform(-tables.period_s, 2 * tables.period_s, 25):
        a, b = tables(s), tables.exact(s)
        for name in ("q", "qd", "tau"):
            err = np.abs(getattr(a, name) - getattr(b, name)).max()
            assert err <= 1e-8 * max(np.abs(getattr(b, name)).max(), 1.0), name
        for name in ("m_r", "m_r_d", "w_r", "w_r_d"):
            assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-8, abs=1e-10), name
    pair = tables.pair(0.7, 1.9)
    np.testing.assert_array_equal(pair[0].tau, tables(0.7).tau)
    np.testing.assert_array_equal(pair[1].q, tables(1.9).q)


def test_two_link_tables_with_analytic_model_match_bullet_model() -> None:
    spec = two_link()
    path = default_path(spec)
    a = PathTables(path, TwoLinkAnalyticModel())
    b = PathTables(path, BulletModel(spec))
    for s in (0.1, 1.7, 3.3):
        np.testing.assert_allclose(a(s).tau, b(s).tau, atol=1e-10)
        assert a(s).w_r == pytest.approx(b(s).w_r, abs=1e-10)


def test_stationary_path_is_rejected_naming_where() -> None:
    spec = make_robot("iiwa")
    model = BulletModel(spec)
    # All joints share one phase: q_r' = 0 at s = S/4 and 3S/4 — the arm stops there.
    amp = np.full((1, spec.n), 0.2)
    path = MultiSinePath(np.array(spec.home_q_rad), amp, np.zeros((1, spec.n)), period_s=4.0)
    with pytest.raises(InvalidPathError, match=r"stationary.*s = (1\.0|3\.0)"):
        PathTables(path, model)
    with pytest.raises(InvalidPathError, match="stationary"):
        PathTables(MultiSinePath(np.array(spec.home_q_rad), 0 * amp, 0 * amp, 4.0), model)
    model.close()


def test_path_outside_joint_limits_is_rejected_naming_joint() -> None:
    spec = two_link()
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


def test_random_paths_are_seeded_and_valid() -> None:
    spec = make_robot("panda")
    a = random_multisine(spec, np.random.default_rng(7))
    b = random_multisine(spec, np.random.default_rng(7))
    c = random_multisine(spec, np.random.default_rng(8))
    np.testing.assert_array_equal(a.evaluate(1.3)[0], b.evaluate(1.3)[0])
    assert not np.array_equal(a.evaluate(1.3)[0], c.evaluate(1.3)[0])
    model = BulletModel(spec)
    for seed in range(5):
        path = random_multisine(spec, np.random.default_rng(seed))
        check_joint_limits(path, *spec.limits())
        PathTables(path, model, grid_size=256)
    model.close()


def test_ee_circle_path_follows_the_circle() -> None:
    spec = two_link()
    center, radius = np.array([0.5, 0.0, -0.3]), 0.15
    path = ee_circle_path(spec, center, radius, normal=(0.0, 1.0, 0.0), n_samples=128)
    fk = TwoLinkAnalyticModel()
    s = np.linspace(0.0, path.period_s, 301)
    q = path.evaluate(s)[0]
    tip = np.array([fk.ee_position(qi) for qi in q])  # (x, z)
    r = np.linalg.norm(tip - center[[0, 2]], axis=1)
    # Samples are exact (IK to 1e-10 m); between them the cubic spline deviates O(h⁴).
    np.testing.assert_allclose(r, radius, atol=2e-5)
    PathTables(path, TwoLinkAnalyticModel())  # non-stationary


def test_nearest_matches_brute_force_and_is_zero_on_the_path(robot_tables) -> None:
    spec, _, tables = robot_tables
    path = tables.path
    rng = np.random.default_rng(5)
    for scale in (0.0, 1e-5, 1e-2, 0.2):
        s_true = rng.uniform(0.0, path.period_s)
        q = path.evaluate(s_true)[0] + scale * rng.standard_normal(spec.n)
        near = tables.nearest(q)
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
