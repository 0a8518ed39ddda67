"""Every compiled kernel against its readable numpy twin, to 1e-12 (relative where the
quantity has a scale), on every robot's default path, random paths and a spline path.

The twins: ``MultiSinePath``/``SplinePath.evaluate`` on arrays of s (numpy, scipy) for the
path kernel; ``PathProjector.nearest_numpy`` for the projection; ``TrackingTask.observe_numpy``
and ``sanitize_numpy`` for the task; ``PassivityTables.__call__`` and
``PassivityController.law`` / ``step_numpy`` for the passivity law; ``np.triu`` for the
symmetric mass matrix; ``np.clip`` for actions.
"""

from __future__ import annotations

import numpy as np
import pytest

import ptrack_gym  # noqa: F401
from agents.passivity import PassivityController, PassivityGains
from agents.passivity_kernel import table_point
from agents.passivity_tables import PassivityTables
from agents.policy import checked_action, torque_to_action
from agents.reference_clock import ReferenceClock
from ptrack_gym.envs.task import TrackingTask
from ptrack_gym.kernels.linalg import symmetrize_upper
from ptrack_gym.kernels.projection import coarse_argmin
from ptrack_gym.kernels.task import clip_action
from ptrack_gym.paths import (
    MultiSinePath,
    PathProjector,
    SplinePath,
    default_path,
    random_multisine,
)
from ptrack_gym.robots import ROBOTS, PinocchioModel, robot_profile

TOL = 1e-12


def paths_of(robot: str) -> list[MultiSinePath | SplinePath]:
    """The default path, a random one and a spline through the default path's samples."""
    profile = robot_profile(robot)
    default = default_path(profile)
    samples = default.evaluate(np.linspace(0.0, default.period_s, 64, endpoint=False))[0]
    return [
        default,
        random_multisine(profile, np.random.default_rng(3)),
        SplinePath(samples, default.period_s),
    ]


def rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a − b| / max(|b|, 1), entrywise."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1.0)))


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_path_kernel_equals_the_numpy_evaluation(robot: str) -> None:
    for path in paths_of(robot):
        s = np.concatenate(
            [np.random.default_rng(0).uniform(-2 * path.period_s, 3 * path.period_s, 200),
             np.linspace(0.0, path.period_s, 65)]  # knots of the spline, exactly
        )  # fmt: skip
        batch = path.evaluate(s)  # numpy / scipy
        for i, si in enumerate(s):
            for kernel_value, numpy_value in zip(path.evaluate(float(si)), batch, strict=True):
                assert rel(kernel_value, numpy_value[i]) <= TOL


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_reference_clock_kernel_equals_its_numpy_twin(robot: str) -> None:
    """ReferenceClock.errors (one compiled call) gives errors_numpy's reference and errors
    bit for bit, and the reference is the path's numpy evaluation (to TOL)."""
    model = PinocchioModel(robot_profile(robot))
    rng = np.random.default_rng(7)
    for path in paths_of(robot):
        clock = ReferenceClock(model, path)
        for s in rng.uniform(-path.period_s, 2 * path.period_s, 50):
            clock.reset(float(s))
            q, qd = rng.normal(size=path.n), rng.normal(size=path.n) * 3.0
            fast, slow = clock.errors(q, qd, 1e-3), clock.errors_numpy(q, qd)
            for a, b in zip(fast, slow, strict=True):
                np.testing.assert_array_equal(a, b)
            reference = path.evaluate(np.array([s]))
            for a, b in zip(fast[:3], reference, strict=True):
                assert rel(a, b[0]) <= TOL
            assert rel(fast.e, reference[0][0] - q) <= TOL


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_projection_kernel_equals_the_numpy_search(robot: str) -> None:
    """Same squared distance to 1e-12 (relative, or of 1e-8 rad² for points on the path,
    where both evaluate d² ≈ 0 through cancelling terms); the kernel's s attains it (the
    minimiser itself is only conditioned to ~√ε where the distance is flat, so the two s
    may differ there)."""
    rng = np.random.default_rng(1)
    for path in paths_of(robot):
        projector = PathProjector(path)
        n = path.n
        for scale in (0.0, 1e-6, 1e-3, 0.05, 0.3):
            for _ in range(40):
                q = path.evaluate(rng.uniform(0.0, path.period_s))[0] + scale * rng.normal(size=n)
                k, r = projector.nearest(q), projector.nearest_numpy(q)
                assert abs(k.distance**2 - r.distance**2) <= TOL * max(r.distance**2, 1e-8)
                at_s = float(np.linalg.norm(q - path.evaluate(k.s)[0]))
                # (to the Hermite model's accuracy, ~1e-11 rad on these grids: PathProjector)
                assert abs(at_s - k.distance) <= 1e-10
                if abs(k.s - r.s) > 1e-9:  # a flat minimum: both places are as near
                    at_r = float(np.linalg.norm(q - path.evaluate(r.s)[0]))
                    assert abs(at_r**2 - at_s**2) <= TOL * max(at_s**2, 1e-8)


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_task_kernel_equals_the_numpy_task(robot: str) -> None:
    """Observation (float32: equal up to the rounding of values 1e-12 apart), reward and
    every info entry of the compiled task against ``observe_numpy``, on usable states and on
    blown-up ones (which both sanitise the same way)."""
    profile = robot_profile(robot)
    model = PinocchioModel(profile)
    rng = np.random.default_rng(2)
    for path in paths_of(robot):
        task = TrackingTask(path, PathProjector(path), model, 50.0, (10.0, 1.0, 0.01), 100.0, True)
        assert task.compiled
        for trial in range(60):
            s_ref = rng.uniform(0.0, path.period_s)
            q = path.evaluate(rng.uniform(0.0, path.period_s))[0] + 0.1 * rng.normal(size=path.n)
            qd = rng.normal(0.0, 2.0, path.n)
            a = rng.uniform(-1.5, 1.5, path.n)
            args = (s_ref, 0.5, a, a * 10.0, rng.normal(size=path.n), 0.25)
            qk, qdk, qn, qdn = q.copy(), qd.copy(), q.copy(), qd.copy()
            if trial % 10 == 9:  # a blow-up, seen without sensors: measured = true arrays
                qk[-1] = qn[-1] = np.inf
                qdk[0] = qdn[0] = np.nan
                obs_k, rew_k, info_k = task.observe(qk, qdk, qk, qdk, *args)
                obs_n, rew_n, info_n = task.observe_numpy(qn, qdn, qn, qdn, *args)
                assert info_k["unstable"] and rew_k == -100.0
            else:
                q_meas = q + 1e-3 * rng.normal(size=path.n)
                qd_meas = qd + 1e-2 * rng.normal(size=path.n)
                obs_k, rew_k, info_k = task.observe(qk, qdk, q_meas, qd_meas, *args)
                obs_n, rew_n, info_n = task.observe_numpy(qn, qdn, q_meas, qd_meas, *args)
            np.testing.assert_array_equal(qk, qn)  # sanitised alike
            np.testing.assert_array_equal(qdk, qdn)
            assert np.all(np.abs(obs_k - obs_n) <= np.spacing(np.abs(obs_n)))
            assert abs(rew_k - rew_n) <= TOL * max(abs(rew_n), 1.0)
            assert info_k.keys() == info_n.keys()
            for key, value in info_n.items():
                if isinstance(value, bool):
                    assert info_k[key] is value, key
                else:
                    assert rel(info_k[key], value) <= TOL, key


def test_sanitize_kernel_equals_numpy() -> None:
    task = TrackingTask(*_two_link_task_args())
    rng = np.random.default_rng(3)
    for trial in range(200):
        q, qd = rng.normal(size=2), rng.normal(0.0, 40.0, 2)
        if trial % 3 == 0:
            q[rng.integers(2)] = rng.choice([np.nan, np.inf, -np.inf])
        if trial % 5 == 0:
            qd[rng.integers(2)] = rng.choice([np.nan, np.inf, 1e3])
        qk, qdk, qn, qdn = q.copy(), qd.copy(), q.copy(), qd.copy()
        assert task.sanitize(qk, qdk) == task.sanitize_numpy(qn, qdn)
        np.testing.assert_array_equal(qk, qn)
        np.testing.assert_array_equal(qdk, qdn)


def _two_link_task_args() -> tuple[object, ...]:
    profile = robot_profile("two_link")
    path = default_path(profile)
    return path, PathProjector(path), PinocchioModel(profile), 50.0, (10.0, 1.0, 0.01), 100.0, False


def test_clip_action_and_symmetrize_equal_numpy() -> None:
    rng = np.random.default_rng(4)
    limits = np.array([40.0, 20.0, 5.0])
    for dtype in (np.float32, np.float64, np.int64):
        a = (rng.uniform(-3, 3, 3)).astype(dtype)
        clipped, tau = np.empty(3), np.empty(3)
        assert clip_action(a, limits, clipped, tau) == -1
        expected = np.minimum(np.maximum(a.astype(np.float64), -1.0), 1.0)
        np.testing.assert_array_equal(clipped, expected)
        np.testing.assert_array_equal(tau, expected * limits)
    assert clip_action(np.array([0.1, np.nan, np.inf]), limits, clipped, tau) == 1
    upper = np.triu(rng.normal(size=(7, 7)))
    out = np.empty((7, 7))
    symmetrize_upper(upper + np.tril(rng.normal(size=(7, 7)), -1), out)  # lower part ignored
    np.testing.assert_array_equal(out, np.triu(upper) + np.triu(upper, 1).T)


@pytest.mark.parametrize("n, n_coarse", [(2, 256), (7, 255), (3, 5), (6, 1)])
def testcoarse_argmin_is_the_first_minimum_of_an_in_order_scan(n: int, n_coarse: int) -> None:
    """The four-lane coarse stage picks the node a plain in-order scan picks, ties (repeated
    nodes) to the lowest index, for any node count (not only multiples of 4)."""
    rng = np.random.default_rng(n * 1000 + n_coarse)

    def scan(q, nodes, sq):  # v_c by the kernel's operations in its order; first strict min
        best, i_best = np.inf, 0
        for c in range(sq.shape[0]):
            dot = 0.0
            for j in range(q.shape[0]):
                dot += nodes[j, c] * q[j]
            if sq[c] - 2.0 * dot < best:
                best, i_best = sq[c] - 2.0 * dot, c
        return i_best

    distinct = rng.normal(size=(n, n_coarse))
    repeated = np.tile(distinct[:, :3], (1, n_coarse // 3 + 1))[:, :n_coarse].copy()
    for nodes in (distinct, repeated):
        sq = np.sum(nodes * nodes, axis=0)
        for scale in (1e-3, 1.0, 30.0):
            for _ in range(200):
                q = rng.normal(size=n) * scale
                assert coarse_argmin(q, nodes, sq) == scan(q, nodes, sq)
    assert coarse_argmin(np.full(n, np.nan), distinct, np.sum(distinct**2, axis=0)) == 0


def test_checked_action_equals_the_numpy_conversion_and_check() -> None:
    """The policy adapter's kernel: torque_to_action's action bit for bit (inside and beyond
    the limits, tiny and huge torques), and the first non-finite entry found like
    require_finite_torque finds it."""
    rng = np.random.default_rng(5)
    limits = np.array([320.0, 176.0, 40.0, 1e-3, 7.5])
    for scale in (1e-9, 1.0, 100.0, 1e6):
        tau = rng.normal(size=5) * scale * limits
        action = np.empty(5, dtype=np.float32)
        assert checked_action(tau, limits, action) == -1
        np.testing.assert_array_equal(action, torque_to_action(tau, limits))
    for bad in (np.nan, np.inf, -np.inf):
        tau = np.array([1.0, 2.0, bad, np.nan, 0.0])
        assert checked_action(tau, limits, np.empty(5, dtype=np.float32)) == 2


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_table_kernel_equals_the_spline(robot: str) -> None:
    profile = robot_profile(robot)
    tables = PassivityTables(default_path(profile), PinocchioModel(profile), grid_size=256)
    row = np.empty(3 * profile.n + 4)
    for s in np.concatenate([np.random.default_rng(5).uniform(-10, 20, 100), tables.knots]):
        table_point(tables.knots, tables.coefficients, tables.period_s, float(s), row)
        ref = tables(float(s))
        expected = np.concatenate(
            [ref.q, ref.qd, ref.tau, [ref.m_r, ref.m_r_d, ref.w_r, ref.w_r_d]]
        )
        assert rel(row, expected) <= TOL


@pytest.mark.parametrize("robot", sorted(ROBOTS))
@pytest.mark.parametrize(
    "gains",
    [
        PassivityGains(),
        PassivityGains(K=(50.0,), kappa=3.0, R=0.7, k_pump=5.0, pump="paper"),
        PassivityGains(sync_rate=0.7, sync_ratio=0.6),
    ],
    ids=["default", "paper-pump", "resync"],
)
def test_law_kernel_equals_the_numpy_law(robot: str, gains: PassivityGains) -> None:
    """Every LawOutput field at random states (fast, slow, at rest, off the path) and one
    integration step (the state (s, ṡ, σ) after it) of the compiled law against ``law`` and
    ``step_numpy``."""
    profile = robot_profile(robot)
    model = PinocchioModel(profile)
    tables = PassivityTables(default_path(profile), model, grid_size=256)
    if np.ndim(gains.K) and len(np.atleast_1d(gains.K)) == 1:
        gains = PassivityGains(**{**gains.__dict__, "K": float(np.atleast_1d(gains.K)[0])})
    ctrl = PassivityController(model, tables, gains)
    twin = PassivityController(model, tables, gains)
    rng = np.random.default_rng(6)
    for trial in range(60):
        s = rng.uniform(0.0, tables.period_s)
        q = tables(s).q + rng.normal(0.0, 0.05, profile.n)
        qd = rng.normal(0.0, 0.5, profile.n) * [1.0, 1e-3, 0.0, 1e-9][trial % 4]
        sd = rng.uniform(-0.2, 1.5) if trial % 5 else rng.choice([-1.0, 1.0]) * rng.uniform(3, 60)
        state = (s + rng.normal(0.0, 0.1), sd, s + rng.normal(0.0, 0.1))  # |ṡ| ≫ 1: pump implicit
        ctrl.reset(q, qd, s0=state[0], sd0=state[1], sigma0=state[2])
        twin.reset(q, qd, s0=state[0], sd0=state[1], sigma0=state[2])
        dt = min(1e-3, 0.9 * ctrl.max_period_s())  # arbitrary gains: inside their rate limit
        tau = ctrl.step(q, qd, dt)
        expected = twin.law(q, qd, *state, dt=dt)
        tau_ref = twin.step_numpy(q, qd, dt)
        assert rel(tau, tau_ref) <= TOL
        out = ctrl.last
        assert out is not None
        for field in expected._fields:
            assert rel(getattr(out, field), getattr(expected, field)) <= TOL, field
        assert rel(ctrl._state, twin._state) <= TOL


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_batch_metric_equals_the_mass_matrix_quadratic_form(robot: str) -> None:
    """``PinocchioModel.metric_norms2`` (CRBA per row + the compiled quadratic form of its
    upper triangle) against v ᵀ M(q) v with the full matrix."""
    profile = robot_profile(robot)
    model = PinocchioModel(profile)
    rng = np.random.default_rng(7)
    q = profile.home() + rng.normal(0.0, 0.3, (40, profile.n))
    v = rng.normal(0.0, 1.0, (40, profile.n))
    expected = np.array([vk @ model.mass_matrix(qk) @ vk for qk, vk in zip(q, v, strict=True)])
    assert rel(model.metric_norms2(q, v), expected) <= TOL
    with pytest.raises(ValueError, match="same shape"):
        model.metric_norms2(q, v[:-1])
    # The batch gravity is the per-row gravity, bit for bit.
    np.testing.assert_array_equal(model.gravity_many(q), np.array([model.gravity(qk) for qk in q]))


@pytest.mark.parametrize("robot", ["two_link", "iiwa"])
def test_law_kernel_equals_the_numpy_law_when_the_remedy_scales(robot: str) -> None:
    """The saturation-aware law (tight limits, fast states: α < 1 often) in both twins."""
    profile = robot_profile(robot)
    model = PinocchioModel(profile)
    tables = PassivityTables(default_path(profile), model, grid_size=256)
    limits = tuple(0.05 * x for x in profile.torque_limits_nm)
    gains = PassivityGains(K=40.0, kappa=20.0, R=2.0, k_pump=3.0, torque_limits_nm=limits)
    ctrl, twin = (
        PassivityController(model, tables, gains),
        PassivityController(model, tables, gains),
    )
    rng = np.random.default_rng(8)
    scaled = 0
    for trial in range(60):
        s = rng.uniform(0.0, tables.period_s)
        q = tables(s).q + rng.normal(0.0, 0.05, profile.n)
        qd = tables(s).qd * rng.uniform(0.5, 6.0)
        state = (s, rng.uniform(0.5, 1.5), s + rng.normal(0.0, 0.05))
        ctrl.reset(q, qd, s0=state[0], sd0=state[1], sigma0=state[2])
        # the midpoint hold's δ, scaled into the box, too (inside the gains' rate limit)
        dt = (0.0, min(4e-3, 0.9 * ctrl.max_period_s()))[trial % 2]
        ctrl.step(q, qd, dt)
        out, expected = ctrl.last, twin.law(q, qd, *state, dt=dt)
        assert out is not None
        scaled += expected.r0_scale < 1.0
        for field in expected._fields:
            assert rel(getattr(out, field), getattr(expected, field)) <= TOL, field
    assert scaled > 10


def test_small_solve_equals_numpy_and_refuses_singular_matrices() -> None:
    """``solve_small`` (the midpoint hold's n × n solve) against ``np.linalg.solve`` on random
    well-conditioned systems of n = 1..7; False on a singular matrix."""
    from ptrack_gym.kernels.linalg import solve_small

    rng = np.random.default_rng(9)
    for n in range(1, 8):
        for _ in range(20):
            a = rng.normal(size=(n, n)) + n * np.eye(n)
            b = rng.normal(size=n)
            out = np.empty(n)
            assert solve_small(a, b, out)
            assert rel(out, np.linalg.solve(a, b)) <= 1e-12
    singular = np.array([[1.0, 2.0], [2.0, 4.0]])
    assert not solve_small(singular, np.ones(2), np.empty(2))
    assert not solve_small(np.zeros((3, 3)), np.ones(3), np.empty(3))


@pytest.mark.parametrize("robot", ["two_link", "iiwa"])
@pytest.mark.parametrize("guard", [0.0, 4.0])
def test_stepped_law_kernel_equals_numpy_with_the_hold_memory(robot: str, guard: float) -> None:
    """30 steps of the compiled ``step`` and of ``step_numpy`` on the same measured states
    (near the path, noisy): the torque, (s, ṡ, σ) and the midpoint hold's memory — the
    model's acceleration error estimate b̂ included — agree at every step; with the
    direction guard too, on a nearly stalled arm where it acts."""
    profile = robot_profile(robot)
    model = PinocchioModel(profile)
    tables = PassivityTables(default_path(profile), model, grid_size=256)
    gains = PassivityGains(K=40.0, D=0.04, kappa=20.0, R=2.0, k_pump=3.0)
    ctrl, twin = (
        PassivityController(model, tables, gains, hold_filter_s=0.01, direction_guard=guard)
        for _ in range(2)
    )
    guarded = 0
    rng = np.random.default_rng(10)
    ref = tables(1.0)
    ctrl.reset(ref.q, ref.qd, s0=1.0, sd0=1.0, sigma0=1.0)
    twin.reset(ref.q, ref.qd, s0=1.0, sd0=1.0, sigma0=1.0)
    dt = 2e-3
    for k in range(30):
        r = tables(1.0 + k * dt)
        q, qd = r.q + rng.normal(0.0, 1e-3, profile.n), r.qd + rng.normal(0.0, 0.05, profile.n)
        if guard:  # a nearly stalled arm: the velocity changes by more than itself a period
            qd = 0.01 * r.qd + rng.normal(0.0, 0.002, profile.n)
        assert rel(ctrl.step(q, qd, dt), twin.step_numpy(q, qd, dt)) <= 1e-10, k
        assert rel(ctrl._state, twin._state) <= 1e-10, k
        assert rel(ctrl._hold_state, twin._hold_state) <= 1e-9, k
        out = ctrl.last
        assert out is not None
        speed = np.sqrt(qd @ model.mass_matrix(q) @ qd)
        guarded += (
            out.sigma_dot < speed / np.sqrt(tables(ctrl._state[0] - dt * ctrl._state[1]).m_r) - 1e-9
        )
    assert np.abs(ctrl._hold_state[2 + 2 * profile.n :]).max() > 0.0  # b̂ moved: not vacuous
    assert (guarded > 3) == (guard > 0.0)  # the guard acted at some steps, or never
