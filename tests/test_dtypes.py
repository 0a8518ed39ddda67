"""User arrays of any real dtype or byte order, at every public entry point that hands them
to a compiled kernel: each either works exactly as on the same values in native float64, or
is refused with a package error naming the argument — never numba's ``TypingError`` (numba
types no float16, longdouble or big-endian array) nor a silent out-of-bounds read.

The env's action path (``TrackingEnv.step``) is tested in ``test_env.py``; here: the path
projector (and the metrics through it), the paths, the dynamics models, the task's
observation and sanitisation, the env's reset options, and the controllers of ``agents``.
"""

from __future__ import annotations

import numpy as np
import pytest

from agents.policy import ControllerPolicy
from agents.registry import CONTROLLER_NAMES, make_controller
from ptrack_gym import metrics
from ptrack_gym.envs.tracking import TrackingEnv
from ptrack_gym.errors import InvalidActionError, InvalidConfigError
from ptrack_gym.paths import MultiSinePath, PathProjector, SplinePath, default_path
from ptrack_gym.robots import ROBOTS, BulletModel, PinocchioModel

#: float16, float32, longdouble, big-endian float64, two integer widths, and a strided view.
VARIANTS = ("float16", "float32", "longdouble", ">f8", "int64", "int32", "strided")


def variant(x: object, name: str) -> np.ndarray:
    """``x`` in the dtype ``name``, or (``"strided"``) as a non-contiguous float64 view."""
    arr = np.asarray(x, dtype=np.float64)
    if name != "strided":
        return arr.astype(name)
    wide = np.zeros((*arr.shape, 2))
    wide[..., 0] = arr
    view = wide[..., 0]
    assert arr.ndim == 0 or not view.flags.c_contiguous
    return view


def as_float64(x: np.ndarray) -> np.ndarray:
    """The values of a variant in native, contiguous float64 (what it must act as)."""
    return np.array(x, dtype=np.float64, order="C")


@pytest.fixture(scope="module")
def iiwa():
    """(profile, default path, projector, Pinocchio model, PyBullet model) of the iiwa."""
    profile = ROBOTS["iiwa"]
    path = default_path(profile)
    bullet = BulletModel(profile)
    yield profile, path, PathProjector(path, grid_size=256), PinocchioModel(profile), bullet
    bullet.close()


# -- the path projector and the metrics ---------------------------------------------------


@pytest.mark.parametrize("name", VARIANTS)
def test_projector_and_path_distances_take_any_real_dtype(iiwa, name: str) -> None:
    profile, path, projector, _, _ = iiwa
    q = variant(profile.home() + 0.05, name)
    assert projector.nearest(q) == projector.nearest(as_float64(q))
    rows = variant(path.evaluate(np.array([0.5, 2.0, 3.5]))[0] + 0.02, name)
    for got, want in zip(
        metrics.path_distances(projector, rows),
        metrics.path_distances(projector, as_float64(rows)),
        strict=True,
    ):
        np.testing.assert_array_equal(got, want)


def test_projector_refuses_what_is_not_n_real_numbers(iiwa) -> None:
    """Shapes the kernel would read past (it reads n entries) or cannot type, and non-real
    dtypes, raise InvalidConfigError naming the expected shape."""
    _, _, projector, _, _ = iiwa
    for bad in (np.zeros(8), np.zeros(6), np.zeros((7, 1)), np.zeros((1, 7)), 0.5):
        with pytest.raises(InvalidConfigError, match=r"shape \(7,\)"):
            projector.nearest(bad)
    for bad in (np.zeros(7, dtype=complex), np.zeros(7, dtype=bool), np.array(["0"] * 7)):
        with pytest.raises(InvalidConfigError, match="real numbers"):
            projector.nearest(bad)
    for bad in (np.zeros(7), np.zeros((3, 6))):
        with pytest.raises(InvalidConfigError, match=r"shape \(T, 7\)"):
            projector.nearest_many(bad)


class _PathIn:
    """The iiwa's default path answering in another dtype (a user's path may)."""

    def __init__(self, base: MultiSinePath, name: str) -> None:
        self.base, self.name = base, name
        self.n, self.period_s = base.n, base.period_s

    def evaluate(self, s):
        return tuple(variant(x, self.name) for x in self.base.evaluate(s))


class _PathAsFloat64(_PathIn):
    def evaluate(self, s):
        return tuple(as_float64(x) for x in super().evaluate(s))


@pytest.mark.parametrize("name", VARIANTS)
def test_projector_of_a_path_answering_in_any_real_dtype(iiwa, name: str) -> None:
    """The projector's tables are native float64 whatever the path returns."""
    profile, path, _, _, _ = iiwa
    got = PathProjector(_PathIn(path, name), grid_size=256)
    want = PathProjector(_PathAsFloat64(path, name), grid_size=256)
    for table in (got.grid_q, got.grid_wrapped, got.coarse_q_t, got.hermite, got.hermite_dots):
        assert table.dtype == np.float64 and table.dtype.isnative and table.flags.c_contiguous
    q = profile.home() + 0.05
    assert got.nearest(q) == want.nearest(q)


# -- the paths ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", VARIANTS)
def test_paths_take_any_real_dtype(iiwa, name: str) -> None:
    """Multi-sine and spline paths built from, and evaluated at, arrays of any real dtype
    (a scalar s runs the kernel, an array of s numpy)."""
    _, path, _, _, _ = iiwa
    center, amp, phase = (variant(x, name) for x in (path.center, path.amplitudes, path.phases))
    got = MultiSinePath(center, amp, phase, path.period_s)
    want = MultiSinePath(*(as_float64(x) for x in (center, amp, phase)), path.period_s)
    samples = variant(path.evaluate(np.linspace(0.0, path.period_s, 16, endpoint=False))[0], name)
    spline, spline64 = SplinePath(samples, 8.0), SplinePath(as_float64(samples), 8.0)
    s_scalar, s_array = variant(1.5, name), variant([0.5, 1.5, 7.0], name)
    for p_got, p_want in ((got, want), (spline, spline64), (path, path)):
        for s in (s_scalar, s_scalar[()], s_array):
            for a, b in zip(p_got.evaluate(s), p_want.evaluate(as_float64(s)), strict=True):
                np.testing.assert_array_equal(a, b)


# -- the dynamics models --------------------------------------------------------------------


@pytest.mark.parametrize("name", VARIANTS)
def test_models_take_any_real_dtype(iiwa, name: str) -> None:
    profile, _, _, pin, bullet = iiwa
    rng = np.random.default_rng(3)
    q, qd, qdd = (variant(x, name) for x in (profile.home() + 0.1, rng.normal(0, 2, 7), [1.0] * 7))
    q64, qd64, qdd64 = as_float64(q), as_float64(qd), as_float64(qdd)
    for model in (pin, bullet):
        for method in ("mass_matrix", "gravity", "potential"):
            f = getattr(model, method)
            np.testing.assert_array_equal(f(q), f(q64), err_msg=method)
        np.testing.assert_array_equal(model.coriolis(q, qd), model.coriolis(q64, qd64))
        np.testing.assert_array_equal(
            model.inverse_dynamics(q, qd, qdd), model.inverse_dynamics(q64, qd64, qdd64)
        )
        assert model.kinetic_energy(q, qd) == model.kinetic_energy(q64, qd64)
    np.testing.assert_array_equal(pin.coriolis_matrix(q, qd), pin.coriolis_matrix(q64, qd64))
    rows, rows_d = (variant(np.stack([x, 0.5 * x]), name) for x in (q64, qd64))
    np.testing.assert_array_equal(
        pin.metric_norms2(rows, rows_d), pin.metric_norms2(as_float64(rows), as_float64(rows_d))
    )
    np.testing.assert_array_equal(pin.gravity_many(rows), pin.gravity_many(as_float64(rows)))


def test_metric_norms2_refuses_what_is_not_rows_of_n(iiwa) -> None:
    """One state (n,) instead of rows (T, n), or rows of the wrong width, raise ValueError
    before they reach CRBA or the quadratic-form kernel."""
    _, _, _, pin, _ = iiwa
    for bad in (np.zeros(7), np.zeros((2, 6))):
        with pytest.raises(ValueError, match=r"shape \(T, 7\)"):
            pin.metric_norms2(bad, bad)


# -- the task and the env -------------------------------------------------------------------


@pytest.fixture(scope="module")
def two_link_env():
    env = TrackingEnv(robot="two_link")
    env.reset(seed=0)
    yield env
    env.close()


def _observe(task, q, qd, q_meas, qd_meas, action):
    return task.observe(q, qd, q_meas, qd_meas, 0.7, 0.0, action, np.zeros(2), np.zeros(2), 0.0)


@pytest.mark.parametrize("name", VARIANTS)
def test_task_observe_and_sanitize_take_any_real_dtype(two_link_env, name: str) -> None:
    """Every array of ``TrackingTask.observe`` in one dtype (and the true state also
    separate from the measured one): observation, reward and info as for float64."""
    task = two_link_env.task
    q, qd = variant([0.3, -0.2], name), variant([1.0, -2.0], name)
    action = variant([0.5, -1.0], name)
    for q_meas, qd_meas in ((q, qd), (variant([0.25, -0.1], name), variant([2.0, 1.0], name))):
        got = _observe(task, q, qd, q_meas, qd_meas, action)
        want = _observe(task, *map(as_float64, (q, qd, q_meas, qd_meas, action)))
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1] == want[1]
        assert got[2].keys() == want[2].keys()
        for key in ("path_distance", "path_s", "tracking_error", "reward_effort", "unstable"):
            assert got[2][key] == want[2][key], key
    assert task.sanitize(variant([0.3, -0.2], name), variant([1.0, -2.0], name))


@pytest.mark.parametrize("name", ("float16", "float32", "longdouble", ">f8", "strided"))
def test_task_sanitizes_a_blown_up_state_in_place_in_any_float_dtype(two_link_env, name) -> None:
    """The in-place contract holds where the kernel ran on float64 copies: the caller's
    arrays come back finite (q → 0, q̇ clipped to ±v_max = 50 rad/s)."""
    task = two_link_env.task
    for call in (
        lambda q, qd: _observe(task, q, qd, q, qd, np.zeros(2))[2]["unstable"],
        lambda q, qd: not task.sanitize(q, qd),
    ):
        q, qd = variant([np.nan, 0.3], name), variant([1e4, -1.0], name)
        q1 = float(q[1])  # 0.3 in the dtype
        assert call(q, qd)
        np.testing.assert_array_equal(as_float64(q), [0.0, q1])
        np.testing.assert_array_equal(as_float64(qd), [50.0, -1.0])


def test_task_refuses_misshapen_or_non_real_arrays_it_must_cast(two_link_env) -> None:
    task = two_link_env.task
    q16 = np.zeros(2, dtype=np.float16)
    with pytest.raises(InvalidConfigError, match=r"q must be real numbers of shape \(2,\)"):
        _observe(task, np.zeros(3, dtype=np.float16), q16, q16, q16, np.zeros(2))
    with pytest.raises(InvalidConfigError, match="qd_meas"):
        _observe(task, q16, q16, q16, np.zeros(2, dtype=complex), np.zeros(2))
    with pytest.raises(InvalidActionError, match="action"):
        _observe(task, q16, q16, q16, q16, np.zeros(3, dtype=np.float16))


@pytest.mark.parametrize("name", VARIANTS)
def test_env_reset_options_take_any_real_dtype(two_link_env, name: str) -> None:
    env = two_link_env
    options = {"s0": variant(1.25, name), "q": variant([0.3, -0.2], name)}
    options["qd"] = variant([1.0, -2.0], name)
    got, _ = env.reset(seed=1, options=options)
    want, _ = env.reset(seed=1, options={k: as_float64(v) for k, v in options.items()})
    np.testing.assert_array_equal(got, want)


# -- agents (the controllers' entry points) -------------------------------------------------


@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
def test_controllers_take_any_real_dtype(two_link_env, controller: str) -> None:
    """``reset`` and ``step`` of every controller, and the policy adapter reading the state
    from an observation of any dtype: the torque of the same state in float64."""
    env = two_link_env
    obs, _ = env.reset(seed=2)
    ctrl = make_controller(controller, env)
    q, qd = env.measured_joint_state()
    ctrl.reset(q, qd, env.s0)
    want = ctrl.step(q, qd, env.dt)
    for name in VARIANTS:
        qv, qdv = variant(q, name), variant(qd, name)
        ctrl.reset(qv, qdv, env.s0)
        got = ctrl.step(qv, qdv, env.dt)
        ctrl.reset(as_float64(qv), as_float64(qdv), env.s0)
        np.testing.assert_array_equal(got, ctrl.step(as_float64(qv), as_float64(qdv), env.dt))
    policy = ControllerPolicy(env, make_controller(controller, env), state_source="observation")
    want = policy.predict(obs.astype(np.float64), episode_start=np.array([True]))[0]
    for name in VARIANTS:
        got = policy.predict(variant(obs, name), episode_start=np.array([True]))[0]
        obs64 = as_float64(variant(obs, name))
        np.testing.assert_array_equal(got, policy.predict(obs64, episode_start=np.array([True]))[0])
    assert want.shape == (2,)
