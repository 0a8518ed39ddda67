"""Tests of the tracking environment's contract (Gymnasium API, determinism, lifetime, errors).

Expensive loops use the two-link arm; the iiwa and the Panda appear where a claim is per
robot (API checkers, determinism, rendering, starting states).
"""

from __future__ import annotations

import copy
import gc
import pickle
from collections.abc import Callable
from typing import Any, Protocol

import cloudpickle
import gymnasium as gym
import numpy as np
import pybullet as p
import pytest

import ptrack_gym
from ptrack_gym.envs.config import EnvConfig
from ptrack_gym.envs.tracking import TrackingEnv
from ptrack_gym.errors import InvalidActionError, InvalidConfigError, SimulationClosedError
from ptrack_gym.paths import PathProjector, ReferencePath
from ptrack_gym.robots import BulletModel, PinocchioModel, RobotModel

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
IIWA = "ptrack_gym/IiwaTrack-v0"


class MakeEnv(Protocol):
    """The ``make_env`` fixture (see conftest.py): ``gym.make`` plus closing at teardown."""

    def __call__(self, env_id: str, **kwargs: Any) -> gym.Env[Any, Any]: ...

    def track(self, env: gym.Env[Any, Any]) -> gym.Env[Any, Any]: ...


#: One step's worth of results: observation, reward, terminated, truncated, info.
StepResult = tuple[np.ndarray, float, bool, bool, dict[str, Any]]


# -- helpers ----------------------------------------------------------------------------


def _assert_infos_equal(a: dict[str, Any], b: dict[str, Any]) -> None:
    """Assert two info dicts have the same keys and bit-identical values."""
    assert a.keys() == b.keys()
    for key in a:
        va, vb = a[key], b[key]
        assert type(va) is type(vb), key
        if isinstance(va, np.ndarray):
            assert va.dtype == vb.dtype, key
            assert np.array_equal(va, vb), key
        else:
            assert va == vb, key


def _assert_results_equal(a: list[StepResult], b: list[StepResult]) -> None:
    """Assert two rollouts are bit-identical, step by step."""
    assert len(a) == len(b)
    for k, ((oa, ra, ta, tra, ia), (ob, rb, tb, trb, ib)) in enumerate(zip(a, b, strict=True)):
        assert oa.dtype == ob.dtype, k
        assert np.array_equal(oa, ob), f"observations differ at step {k}"
        assert ra == rb, f"rewards differ at step {k}"
        assert (ta, tra) == (tb, trb), k
        _assert_infos_equal(ia, ib)


def _rollout(env: gym.Env[Any, Any], actions: np.ndarray) -> list[StepResult]:
    """Step through ``actions``; on termination or truncation reset (unseeded) and go on.

    A reset is recorded as ``(obs, 0.0, False, False, info)``, so its observation and info
    are compared too.
    """
    results: list[StepResult] = []
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        results.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, info = env.reset()
            results.append((obs, 0.0, False, False, info))
    return results


def _random_actions(n: int, steps: int, seed: int, scale: float = 1.0) -> np.ndarray:
    """``steps`` actions of size ``n``, uniform in ±``scale``, float32, from a fixed seed."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-scale, scale, size=(steps, n)).astype(np.float32)


def _rss_kb() -> int:
    """Resident set size of this process (kB), from /proc/self/status (VmRSS)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("VmRSS not found in /proc/self/status")  # pragma: no cover


def _connected_clients() -> set[int]:
    """Ids of every connected PyBullet client (PyBullet allows at most 1024)."""
    return {cid for cid in range(1024) if p.isConnected(physicsClientId=cid)}


def _client_ids(env: gym.Env[Any, Any]) -> tuple[int]:
    """The env's PyBullet client ids: the plant's only (the nominal model is Pinocchio's)."""
    return (env.unwrapped.sim.client_id,)


# (1. API checkers: test_robot_battery.py, for every registered robot)


# -- 2. determinism ---------------------------------------------------------------------


@pytest.mark.parametrize("env_id", ptrack_gym.ENV_IDS)
def test_same_seed_gives_bit_identical_rollouts(make_env: MakeEnv, env_id: str) -> None:
    """Two envs reset with one seed agree bit for bit over 1000 random-action steps.

    Unseeded resets after a termination are part of the rollout, so the env's RNG
    stream is compared too.
    """
    env_a, env_b = make_env(env_id), make_env(env_id)
    n = env_a.action_space.shape[0]
    actions = _random_actions(n, 1000, seed=2024)
    obs_a, info_a = env_a.reset(seed=11)
    obs_b, info_b = env_b.reset(seed=11)
    assert np.array_equal(obs_a, obs_b)
    _assert_infos_equal(info_a, info_b)
    rollout_a = _rollout(env_a, actions)
    rollout_b = _rollout(env_b, actions)
    _assert_results_equal(rollout_a, rollout_b)
    # The rollout is not trivially constant.
    assert not np.array_equal(rollout_a[0][0], rollout_a[-1][0])


def test_different_reset_seeds_give_different_observations(
    make_env: MakeEnv,
) -> None:
    """Reset seeds 0 and 1 draw different start phases, hence different observations."""
    env = make_env(TWO_LINK)
    obs_0, info_0 = env.reset(seed=0)
    obs_1, info_1 = env.reset(seed=1)
    assert info_0["s_ref"] != info_1["s_ref"]
    assert not np.array_equal(obs_0, obs_1)
    obs_0_again, _ = env.reset(seed=0)
    assert np.array_equal(obs_0, obs_0_again)


# -- 3. pickling ------------------------------------------------------------------------

_COPIERS: dict[str, Callable[[Any], Any]] = {
    "pickle": lambda obj: pickle.loads(pickle.dumps(obj)),
    "cloudpickle": lambda obj: pickle.loads(cloudpickle.dumps(obj)),
    "deepcopy": copy.deepcopy,
}


@pytest.mark.parametrize("how", sorted(_COPIERS))
def test_copy_mid_episode_continues_identically(make_env: MakeEnv, how: str) -> None:
    """A copy taken after 100 steps and the original then agree for 200 steps and a reset.

    The copy owns new PyBullet clients; closing it leaves the original usable.
    """
    env = make_env(TWO_LINK)
    actions = _random_actions(2, 300, seed=5)
    env.reset(seed=3)
    for action in actions[:100]:
        env.step(action)
    clone = make_env.track(_COPIERS[how](env))
    assert set(_client_ids(clone)).isdisjoint(_client_ids(env))
    assert clone.unwrapped.t == env.unwrapped.t
    _assert_results_equal(_rollout(env, actions[100:]), _rollout(clone, actions[100:]))
    # The RNG travelled with the copy: an unseeded reset draws the same start.
    obs_a, info_a = env.reset()
    obs_b, info_b = clone.reset()
    assert np.array_equal(obs_a, obs_b)
    _assert_infos_equal(info_a, info_b)
    clone.close()
    env.step(actions[0])  # the original is unaffected by closing the copy


def test_pickled_copy_rng_survives_reading_np_random_seed(make_env: MakeEnv) -> None:
    """Reading ``np_random_seed`` on a copy must not change what its next reset draws.

    Regression: ``__setstate__`` once restored ``_np_random`` but not ``_np_random_seed``,
    and Gymnasium's ``np_random_seed`` property, seeing None, replaced the generator.
    """
    env = make_env(TWO_LINK)
    env.reset(seed=3)
    clone = make_env.track(pickle.loads(pickle.dumps(env)))
    assert clone.np_random_seed == env.np_random_seed
    obs_a, _ = env.reset()
    obs_b, _ = clone.reset()
    assert np.array_equal(obs_a, obs_b)


def test_pickled_copy_keeps_spec(make_env: MakeEnv) -> None:
    """A pickled copy of a ``gym.make`` env still knows its registered spec.

    Regression: the ``EnvSpec`` that ``gym.make`` attaches was once dropped by pickling.
    """
    env = make_env(TWO_LINK)
    clone = make_env.track(pickle.loads(pickle.dumps(env)))
    assert clone.unwrapped.spec is not None
    assert clone.unwrapped.spec.id == TWO_LINK


# -- 4. closing -------------------------------------------------------------------------


def test_close_twice_is_fine_and_a_closed_env_refuses_to_run() -> None:
    """``close()`` is idempotent for wrapped and bare envs; using one afterwards raises."""
    wrapped = gym.make(TWO_LINK)
    wrapped.reset(seed=0)
    wrapped.close()
    wrapped.close()
    bare = TrackingEnv(robot="two_link")
    bare.reset(seed=0)
    bare.close()
    bare.close()
    for env in (wrapped.unwrapped, bare):
        assert not env.sim.connected
        with pytest.raises(SimulationClosedError):
            env.step(np.zeros(2))
        with pytest.raises(SimulationClosedError):
            env.reset(seed=0)


def test_closed_bullet_sim_raises_simulation_closed_error() -> None:
    """The env's own BulletSim, once closed, refuses to step (and it is a RuntimeError)."""
    env = TrackingEnv(robot="two_link")
    env.close()
    with pytest.raises(SimulationClosedError, match="closed"):
        env.sim.step()
    assert issubclass(SimulationClosedError, RuntimeError)


def test_render_after_close_raises_simulation_closed_error(make_env: MakeEnv) -> None:
    """A closed env must not render, even when a newer env has taken its client id."""
    closed = gym.make(TWO_LINK, render_mode="rgb_array")
    closed.reset(seed=0)
    closed.close()
    make_env(TWO_LINK, render_mode="rgb_array").reset(seed=1)  # may reuse the client id
    with pytest.raises(SimulationClosedError):
        closed.unwrapped.render()


# -- 5. memory and PyBullet clients -----------------------------------------------------

#: RSS growth allowed over 200 make/reset/step/close cycles (kB). Measured run to run on
#: this machine (with two clients per env, before the nominal model became Pinocchio's):
#: between -0.8 MB and +1.7 MB (allocator noise). One live env holds a PyBullet client of
#: ~25-28 MB plus its Pinocchio model and path projector, so leaking either for each of
#: 200 envs would add ≥ 200 MB; 16 MB catches any leak of ≥ 80 kB per env while staying
#: 10x above the noise.
_RSS_TOLERANCE_KB = 16 * 1024


def test_creating_and_closing_200_envs_keeps_memory_flat_and_frees_clients() -> None:
    """200 make/reset/step/close cycles leave RSS flat and no PyBullet client connected."""

    def cycle(seed: int) -> None:
        env = gym.make(TWO_LINK)
        env.reset(seed=seed)
        env.step(np.zeros(2, dtype=np.float32))
        ids = _client_ids(env)
        assert all(p.isConnected(physicsClientId=cid) for cid in ids)
        env.close()
        assert not any(p.isConnected(physicsClientId=cid) for cid in ids)

    for seed in range(20):  # warm-up: imports, allocator arenas, URDF caches
        cycle(seed)
    gc.collect()
    clients_before = _connected_clients()
    rss_before_kb = _rss_kb()
    for seed in range(200):
        cycle(seed)
    gc.collect()
    growth_kb = _rss_kb() - rss_before_kb
    assert growth_kb < _RSS_TOLERANCE_KB, f"RSS grew by {growth_kb} kB over 200 envs"
    assert _connected_clients() == clients_before


# -- 6. bad input -----------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(3,), (1,), (1, 2), (2, 1), ()])
def test_wrong_action_shape_raises_invalid_action_error(
    make_env: MakeEnv, shape: tuple[int, ...]
) -> None:
    """An action of the wrong shape raises InvalidActionError, a ValueError."""
    env = make_env(TWO_LINK)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape") as excinfo:
        env.step(np.zeros(shape, dtype=np.float32))
    assert isinstance(excinfo.value, InvalidActionError)


def test_non_finite_action_names_indices_and_leaves_state_untouched(
    make_env: MakeEnv,
) -> None:
    """NaN/inf entries raise a ValueError naming them; state, time and RNG are unchanged.

    The env that saw the bad action then steps exactly like a twin that never did.
    """
    env, twin = make_env(IIWA), make_env(IIWA)
    env.reset(seed=4)
    twin.reset(seed=4)
    good = np.full(7, 0.01, dtype=np.float32)
    env.step(good)
    twin.step(good)
    unwrapped = env.unwrapped
    q_before, qd_before = unwrapped.joint_state()
    plant_before = unwrapped.arm.state()
    t_before = unwrapped.t
    bad = good.copy()
    bad[[2, 5, 6]] = [np.nan, np.inf, -np.inf]
    with pytest.raises(ValueError, match=r"indices \[2, 5, 6\]") as excinfo:
        env.step(bad)
    assert isinstance(excinfo.value, InvalidActionError)
    q_after, qd_after = unwrapped.joint_state()
    assert np.array_equal(q_after, q_before)
    assert np.array_equal(qd_after, qd_before)
    for before, after in zip(plant_before, unwrapped.arm.state(), strict=True):
        assert np.array_equal(before, after)
    assert unwrapped.t == t_before
    _assert_results_equal([env.step(good)], [twin.step(good)])


def test_out_of_range_action_acts_exactly_as_clipped_action(
    make_env: MakeEnv,
) -> None:
    """Actions up to ±7 give the same observations, rewards and infos as clipped ones."""
    env, twin = make_env(TWO_LINK), make_env(TWO_LINK)
    raw = _random_actions(2, 50, seed=9, scale=7.0)
    raw[0] = [3.0, -7.0]
    clipped = np.clip(raw, -1.0, 1.0)
    assert np.mean(np.abs(raw) > 1.0) > 0.5  # most entries really are out of range
    env.reset(seed=8)
    twin.reset(seed=8)
    _assert_results_equal(_rollout(env, raw), _rollout(twin, clipped))


def test_unknown_make_kwarg_raises_type_error() -> None:
    """``gym.make`` with an argument the env does not take raises TypeError."""
    with pytest.raises(TypeError, match="not_an_option"):
        gym.make(TWO_LINK, not_an_option=1)


@pytest.mark.parametrize(
    ("physics_hz", "control_hz"),
    [
        (1000.0, 300.0),
        (1000.0, 2000.0),
        (1000.0, 0.0),
        (0.0, 1000.0),
        (-1000.0, -100.0),
        (1000.0, float("nan")),
        (float("nan"), 1000.0),
        (1000.0, float("inf")),
        (float("inf"), 1000.0),
        (1e300, 1e-300),
    ],
)
def test_bad_rates_raise_value_error(physics_hz: float, control_hz: float) -> None:
    """control_hz must divide physics_hz, both positive and finite: else InvalidConfigError
    naming the rate at fault.

    Regressions: control_hz=inf once passed (1000/inf = 0 rounds to itself, giving 0
    sub-steps and dt = 0), and an infinite ratio once raised OverflowError from round().
    """
    with pytest.raises(ValueError, match=r"(physics|control)_hz") as excinfo:
        gym.make(TWO_LINK, physics_hz=physics_hz, control_hz=control_hz)
    assert isinstance(excinfo.value, InvalidConfigError)


@pytest.mark.parametrize(
    ("physics_hz", "control_hz"), [(np.int64(1000), 100.0), (1000.0, np.float32(100.0))]
)
def test_numpy_scalar_rates_are_accepted(
    make_env: MakeEnv, physics_hz: float, control_hz: float
) -> None:
    """Rates given as NumPy scalars (e.g. from ``np.array([100, 1000])``) work like floats."""
    env = make_env(TWO_LINK, physics_hz=physics_hz, control_hz=control_hz)
    assert env.unwrapped.substeps == 10
    assert env.unwrapped.dt == 0.01


def test_unknown_reset_option_raises_value_error(
    make_env: MakeEnv,
) -> None:
    """Reset options other than s0, q, qd raise InvalidConfigError naming them."""
    env = make_env(TWO_LINK)
    with pytest.raises(ValueError, match="q0") as excinfo:
        env.reset(seed=0, options={"q0": np.zeros(2)})
    assert isinstance(excinfo.value, InvalidConfigError)


def _assert_unstable_step(env: gym.Env[Any, Any], result: StepResult) -> None:
    """The documented outcome of an unstable step."""
    obs, reward, terminated, truncated, info = result
    assert terminated is True
    assert truncated is False
    assert info["unstable"] is True
    assert np.all(np.isfinite(obs))
    assert env.observation_space.contains(obs)
    assert np.isfinite(reward)
    assert reward == -env.unwrapped.config.unstable_penalty


def test_speed_above_limit_terminates_as_unstable(
    make_env: MakeEnv,
) -> None:
    """A start with q̇ above ``max_joint_speed_rad_s`` (via reset options) ends the episode.

    Joint 1 starts at 1.5 v_max, below PyBullet's 100 rad/s clamp; with zero torque one
    millisecond cannot slow it below v_max.
    """
    env = make_env(TWO_LINK)
    v_max = env.unwrapped.robot_profile.max_joint_speed_rad_s
    obs, _ = env.reset(seed=0, options={"qd": np.array([1.5 * v_max, 0.0])})
    assert env.observation_space.contains(obs)  # the reset observation is clipped too
    result = env.step(np.zeros(2, dtype=np.float32))
    _assert_unstable_step(env, result)
    assert np.max(np.abs(env.unwrapped.joint_state()[1])) <= v_max  # reported clipped


def test_full_wrist_torque_on_iiwa_blows_up_and_terminates(
    make_env: MakeEnv,
) -> None:
    """Physics-driven instability: the iiwa's light last link under its full 40 N·m.

    Its inertia about the joint axis is ~1e-3 kg·m², so q̈ ~ 4e4 rad/s² and |q̇₇| passes
    v_max = 50 rad/s on the 2nd millisecond, long before the joint limit: the episode
    must end as unstable within a few steps.
    """
    env = make_env(IIWA)
    env.reset(seed=0)
    action = np.zeros(7, dtype=np.float32)
    action[6] = 1.0
    for _ in range(10):
        result = env.step(action)
        if result[2]:
            break
    _assert_unstable_step(env, result)


# -- 7. rates ---------------------------------------------------------------------------


def test_rates_set_dt_substeps_and_time(make_env: MakeEnv) -> None:
    """control_hz=100, physics_hz=1000: dt = 0.01 s, 10 sub-steps, t_s grows 0.01 per step.

    t_s is a running sum of dt, so it is compared to k·dt within a few ulps (1e-15 s).
    """
    env = make_env(TWO_LINK, control_hz=100.0, physics_hz=1000.0)
    unwrapped = env.unwrapped
    assert unwrapped.dt == 0.01
    assert unwrapped.physics_dt == 0.001
    assert unwrapped.substeps == 10
    _, info = env.reset(seed=0)
    assert info["t_s"] == 0.0
    s0 = info["s_ref"]
    for k in range(1, 21):
        _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
        assert info["t_s"] == pytest.approx(0.01 * k, rel=0.0, abs=1e-15)
        assert info["s_ref"] == pytest.approx(s0 + 0.01 * k, rel=0.0, abs=1e-14)


def test_one_slow_step_equals_ten_fast_steps(make_env: MakeEnv) -> None:
    """At 100 Hz one step holds the torque over 10 physics steps: the same plant state,
    bit for bit, as 10 steps of the same action at 1 kHz."""
    slow = make_env(TWO_LINK, control_hz=100.0, physics_hz=1000.0)
    fast = make_env(TWO_LINK, control_hz=1000.0, physics_hz=1000.0)
    slow.reset(seed=2)
    fast.reset(seed=2)
    action = np.array([0.7, -0.4], dtype=np.float32)
    for _ in range(3):
        slow.step(action)
        for _ in range(10):
            fast.step(action)
        q_slow, qd_slow = slow.unwrapped.joint_state()
        q_fast, qd_fast = fast.unwrapped.joint_state()
        assert np.array_equal(q_slow, q_fast)
        assert np.array_equal(qd_slow, qd_fast)


# -- 8. rendering -----------------------------------------------------------------------


@pytest.mark.parametrize("env_id", ptrack_gym.ENV_IDS)
def test_rgb_array_render_is_a_headless_image_of_the_arm(
    make_env: MakeEnv, env_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``rgb_array`` gives a (240, 320, 3) uint8 frame without a display, showing the arm.

    The arm is visible: the frame is not uniform, and moving the arm changes it.
    """
    monkeypatch.delenv("DISPLAY", raising=False)
    env = make_env(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert isinstance(frame, np.ndarray)
    assert frame.shape == (240, 320, 3)
    assert frame.dtype == np.uint8
    assert not np.all(frame == frame[0, 0])
    home = np.array(env.unwrapped.robot_profile.home_q_rad)
    env.reset(seed=0, options={"q": home + 0.5, "qd": np.zeros_like(home)})
    assert not np.array_equal(env.render(), frame)


def test_render_without_render_mode_returns_none(
    make_env: MakeEnv,
) -> None:
    """With ``render_mode=None`` the bare env renders nothing."""
    env = make_env(TWO_LINK)
    env.reset(seed=0)
    assert env.unwrapped.render() is None


# -- 9. starting states -----------------------------------------------------------------


@pytest.mark.parametrize("env_id", ptrack_gym.ENV_IDS)
def test_on_path_start_is_on_the_path_with_path_velocity(make_env: MakeEnv, env_id: str) -> None:
    """start="on_path", no noise: q = q_r(s₀), q̇ = q_r'(s₀) exactly, path distance < 1e-9."""
    env = make_env(env_id, start="on_path", start_noise_rad=0.0)
    unwrapped = env.unwrapped
    n = unwrapped.n
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        q_r, qd_r, _ = unwrapped.path.evaluate(info["s_ref"])
        q, qd = unwrapped.joint_state()
        assert np.array_equal(q, q_r)
        assert np.array_equal(qd, qd_r)
        assert info["path_distance"] < 1e-9
        assert info["tracking_error"] == 0.0
        assert np.array_equal(obs[4 * n : 6 * n], np.zeros(2 * n, dtype=np.float32))


def test_rest_near_path_start_is_at_rest_within_the_offset(
    make_env: MakeEnv,
) -> None:
    """start="rest_near_path": q̇ = 0 and |q − q_r(s₀)| ≤ start_offset_rad per joint."""
    offset = 0.1
    env = make_env(TWO_LINK, start="rest_near_path", start_offset_rad=offset)
    unwrapped = env.unwrapped
    deviations = []
    for seed in range(20):
        _, info = env.reset(seed=seed)
        q_r = unwrapped.path.evaluate(info["s_ref"])[0]
        q, qd = unwrapped.joint_state()
        assert np.array_equal(qd, np.zeros(2))
        assert np.all(np.abs(q - q_r) <= offset)
        deviations.append(np.abs(q - q_r))
    assert np.max(deviations) > 0.5 * offset  # the offset is really applied


def test_s0_option_sets_the_start_phase(make_env: MakeEnv) -> None:
    """reset(options={"s0": 1.0}) starts at s_ref = 1.0, t = 0, on q_r(1.0)."""
    env = make_env(TWO_LINK)
    _, info = env.reset(seed=0, options={"s0": 1.0})
    assert info["s_ref"] == 1.0
    assert info["t_s"] == 0.0
    assert env.unwrapped.s0 == 1.0
    q, _ = env.unwrapped.joint_state()
    assert np.array_equal(q, env.unwrapped.path.evaluate(1.0)[0])


def test_q_and_qd_options_set_the_start_state(
    make_env: MakeEnv,
) -> None:
    """reset(options={"q": …, "qd": …}) teleports the plant there exactly."""
    env = make_env(TWO_LINK)
    q0, qd0 = np.array([-0.3, 0.8]), np.array([0.5, -1.25])
    env.reset(seed=0, options={"q": q0, "qd": qd0})
    q, qd = env.unwrapped.joint_state()
    assert np.array_equal(q, q0)
    assert np.array_equal(qd, qd0)


# -- 10. attributes ---------------------------------------------------------------------


@pytest.mark.parametrize("env_id", ptrack_gym.ENV_IDS)
def test_unwrapped_exposes_model_path_dt_projector(make_env: MakeEnv, env_id: str) -> None:
    """``env.unwrapped`` has the nominal model, the path, dt and the path's projector."""
    env = make_env(env_id)
    unwrapped = env.unwrapped
    assert isinstance(unwrapped, TrackingEnv)
    assert isinstance(unwrapped.model, PinocchioModel)
    assert isinstance(unwrapped.model, RobotModel)
    assert isinstance(unwrapped.path, ReferencePath)
    assert isinstance(unwrapped.projector, PathProjector)
    assert unwrapped.projector.path is unwrapped.path
    assert unwrapped.dt == 1e-3
    assert unwrapped.model.n == unwrapped.path.n == unwrapped.n


# -- 11. info quantities ----------------------------------------------------------------


@pytest.mark.parametrize(("env_id", "scale"), [(TWO_LINK, 0.3), (IIWA, 0.02)])
def test_info_energy_and_errors_are_the_nominal_models_at_the_true_state(
    make_env: MakeEnv, env_id: str, scale: float
) -> None:
    """With ``info_energy=True``, ``energy_j`` = ½q̇ᵀM(q)q̇ + U(q) of the nominal model (checked
    against an independent PyBullet model), ``tracking_error`` and ``path_distance`` at the
    true state, every step, also with the plant's masses changed (which must not leak)."""
    env = make_env(env_id, disturbance=("mismatch", 1.0), info_energy=True)
    u = env.unwrapped
    reference = BulletModel(u.robot_profile)
    env.reset(seed=4)
    for action in _random_actions(u.n, 400, seed=9, scale=scale):
        _, _, terminated, _, info = env.step(action)
        assert not terminated
        q, qd = u.joint_state()
        expected = reference.kinetic_energy(q, qd) + reference.potential(q)
        assert info["energy_j"] == pytest.approx(expected, rel=1e-12, abs=1e-12)
        q_ref = u.path.evaluate(info["s_ref"])[0]
        assert info["tracking_error"] == pytest.approx(np.linalg.norm(q_ref - q), abs=1e-14)
        assert info["path_distance"] == pytest.approx(u.projector.nearest(q).distance, abs=1e-15)
    assert np.max(np.abs(u.arm.link_masses() - reference.link_masses_kg)) > 1e-3  # perturbed
    reference.close()


def test_energy_is_in_the_info_only_when_asked_for(make_env: MakeEnv) -> None:
    env = make_env(TWO_LINK)
    _, info = env.reset(seed=0)
    assert "energy_j" not in info
    assert "energy_j" not in env.step(np.zeros(2, dtype=np.float32))[4]
    env = make_env(TWO_LINK, info_energy=True)
    _, info = env.reset(seed=0)
    assert np.isfinite(info["energy_j"])


# -- 12. bad arguments found by trying the env as a new user would ----------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"reward_weights": (10.0, float("nan"), 0.01)}, "reward_weights"),
        ({"reward_weights": (10.0, 1.0, float("inf"))}, "reward_weights"),
        ({"reward_weights": (10.0, -1.0, 0.01)}, "reward_weights"),
        ({"reward_weights": (10.0, 1.0)}, "reward_weights"),
        ({"reward_weights": "abc"}, "reward_weights"),
        ({"unstable_penalty": float("nan")}, "unstable_penalty"),
        ({"unstable_penalty": float("inf")}, "unstable_penalty"),
        ({"start_offset_rad": float("inf")}, "start_offset_rad"),
        ({"start_offset_rad": -0.1}, "start_offset_rad"),
        ({"start_noise_rad": float("nan")}, "start_noise_rad"),
        ({"control_hz": True}, "control_hz"),
        ({"physics_hz": "1000"}, "physics_hz"),
        ({"horizon_s": 0.0}, "horizon_s"),
        ({"path": "spiral"}, "path"),
        ({"path_seed": 1.5}, "path_seed"),
        ({"start": "flying"}, "start"),
        ({"info_energy": 1}, "info_energy"),
        ({"render_mode": "human"}, "render_mode"),
        ({"robot": "ur5"}, "unknown robot"),
    ],
)
def test_bad_arguments_raise_at_construction(kwargs: dict[str, Any], match: str) -> None:
    """Each bad value is refused by the constructor with a message naming the argument,
    before any PyBullet client is connected."""
    before = _connected_clients()
    with pytest.raises(InvalidConfigError, match=match):
        TrackingEnv(**kwargs)
    with pytest.raises(ValueError, match=match):
        EnvConfig(**kwargs)
    assert _connected_clients() == before


def test_env_signature_defaults_are_the_validators() -> None:
    """The env's keyword defaults and :class:`EnvConfig`'s are the same (one contract)."""
    import inspect

    env_defaults = {
        k: v.default for k, v in inspect.signature(TrackingEnv.__init__).parameters.items()
        if k != "self"
    }  # fmt: skip
    assert env_defaults == EnvConfig().kwargs()


@pytest.mark.parametrize(
    "action",
    [
        np.array([0.1 + 0.2j, 0.0]),
        np.array(["0.1", "0.2"]),
        np.array([True, False]),
        np.array([None, None], dtype=object),
    ],
    ids=["complex", "string", "bool", "object"],
)
def test_non_real_actions_are_refused_not_cast(make_env: MakeEnv, action: np.ndarray) -> None:
    env = make_env(TWO_LINK)
    env.reset(seed=0)
    before = env.unwrapped.joint_state()
    with pytest.raises(InvalidActionError, match="real numbers"):
        env.unwrapped.step(action)
    assert np.array_equal(env.unwrapped.joint_state()[0], before[0])


def test_integer_actions_are_accepted_as_numbers(make_env: MakeEnv) -> None:
    env, twin = make_env(TWO_LINK), make_env(TWO_LINK)
    env.reset(seed=0)
    twin.reset(seed=0)
    _assert_results_equal(
        [env.unwrapped.step(np.array([1, 0]))], [twin.unwrapped.step(np.array([1.0, 0.0]))]
    )


@pytest.mark.parametrize(
    "dtype", [np.float16, np.longdouble, np.dtype(">f8"), np.dtype(">f4"), np.int16],
    ids=["float16", "longdouble", "big-endian-f8", "big-endian-f4", "int16"],
)  # fmt: skip
def test_actions_of_any_real_dtype_or_byte_order_step_as_their_float64_values(
    make_env: MakeEnv, dtype: np.dtype
) -> None:
    """The action kernel is compiled for native floats: other real dtypes and byte orders
    are cast, and step exactly as the float64 array of the same values."""
    env, twin = make_env(TWO_LINK), make_env(TWO_LINK)
    env.reset(seed=0)
    twin.reset(seed=0)
    action = np.array([0.5, -1.0]).astype(dtype)
    _assert_results_equal(
        [env.unwrapped.step(action)], [twin.unwrapped.step(action.astype(np.float64))]
    )


def test_a_longdouble_action_beyond_float64_is_refused_as_non_finite(make_env: MakeEnv) -> None:
    env = make_env(TWO_LINK)
    env.reset(seed=0)
    huge = np.array([np.longdouble(10.0) ** 400, 0.0], dtype=np.longdouble)
    with np.errstate(over="ignore"):
        if np.isfinite(huge.astype(np.float64)).all():  # longdouble is float64 here
            pytest.skip("numpy's longdouble is float64 on this platform")
    before = env.unwrapped.joint_state()
    with pytest.raises(InvalidActionError, match="non-finite"):
        env.unwrapped.step(huge)
    assert np.array_equal(env.unwrapped.joint_state()[0], before[0])


@pytest.mark.parametrize("disturbance", [None, "impulse"])
def test_stepping_the_unwrapped_env_before_reset_raises_reset_needed(
    disturbance: str | None,
) -> None:
    env = TrackingEnv(robot="two_link", disturbance=disturbance)
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        env.step(np.zeros(2))
    with pytest.raises(gym.error.ResetNeeded):
        env.disturbance_schedule()
    env.reset(seed=0)
    env.step(np.zeros(2))
    env.close()
