"""The passivity controller's tables: the exact identities of CONTROL_LAW.md checked against
finite differences, interpolation accuracy, the analytic two-link model, and the rejection of
stationary paths naming where."""

from __future__ import annotations

import numpy as np
import pytest

from agents.passivity_tables import PassivityTables, passivity_tables
from ptrack_gym.errors import InvalidPathError
from ptrack_gym.paths import MultiSinePath, default_path
from ptrack_gym.robots import ROBOTS, BulletModel, PinocchioModel, robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot_tables(request):
    profile = robot_profile(request.param)
    model = PinocchioModel(profile)
    yield profile, model, PassivityTables(default_path(profile), model)


def fd(f, s, h=1e-5):
    return (f(s + h) - f(s - h)) / (2 * h)


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


def test_two_link_tables_with_analytic_model_match_both_library_models() -> None:
    spec = robot_profile("two_link")
    path = default_path(spec)
    a = PassivityTables(path, TwoLinkAnalyticModel())
    bullet = BulletModel(spec)
    for other in (PinocchioModel(spec), bullet):
        b = PassivityTables(path, other)
        for s in (0.1, 1.7, 3.3):
            np.testing.assert_allclose(a(s).tau, b(s).tau, atol=1e-10)
            assert a(s).w_r == pytest.approx(b(s).w_r, abs=1e-10)
    bullet.close()


def test_tables_are_shared_per_path_and_model() -> None:
    spec = robot_profile("two_link")
    path, model = default_path(spec), PinocchioModel(spec)
    assert passivity_tables(path, model) is passivity_tables(path, model)
    # Shared by content: an equal model of the same robot hits the same tables.
    assert passivity_tables(path, PinocchioModel(spec)) is passivity_tables(path, model)
    other = default_path(spec, period_s=5.0)
    assert passivity_tables(other, model) is not passivity_tables(path, model)
    analytic = TwoLinkAnalyticModel()  # no cache key: tables of its own
    assert passivity_tables(path, analytic) is not passivity_tables(path, analytic)


def test_stationary_path_is_rejected_naming_where() -> None:
    spec = robot_profile("iiwa")
    model = PinocchioModel(spec)
    # All joints share one phase: q_r' = 0 at s = S/4 and 3S/4 — the arm stops there.
    amp = np.full((1, spec.n), 0.2)
    path = MultiSinePath(np.array(spec.home_q_rad), amp, np.zeros((1, spec.n)), period_s=4.0)
    with pytest.raises(InvalidPathError, match=r"stationary.*s = (1\.0|3\.0)"):
        PassivityTables(path, model)
    with pytest.raises(InvalidPathError, match="stationary"):
        PassivityTables(MultiSinePath(np.array(spec.home_q_rad), 0 * amp, 0 * amp, 4.0), model)
