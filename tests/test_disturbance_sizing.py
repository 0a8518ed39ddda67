"""Joint-torque disturbances sized by M(q_home) (``sizing="home"``, the default) or by the
nominal M(q) at the configuration where they start to act (``sizing="onset"``): the home
numbers are those of before, the onset numbers are M(q_onset) computed from the env's
model at the true state, the two sizings of one seed are paired, bad values and a missing
mass matrix are refused, and an onset-sized episode is deterministic."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the envs)
from ptrack_gym.disturbances import (
    SIZINGS,
    DisturbanceContext,
    DisturbanceRunner,
    ImpulseTorque,
    NoiseTorque,
    PeriodicTorque,
    StepTorque,
    build_disturbances,
)
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import robot_profile

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
ALPHA = 4.0  # rad/s²
DIRECTION = (0.6, -0.8)  # a unit vector already: its normalisation is exact


def make(disturbance, **kwargs):
    return gym.make(TWO_LINK, disturbance=disturbance, **kwargs).unwrapped


def run(env, seed: int, steps: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(q before each step, the disturbance torque of each step's last sub-step), zero action."""
    env.reset(seed=seed)
    qs, taus = [], []
    for _ in range(steps):
        qs.append(env.joint_state()[0])
        taus.append(env.step(np.zeros(env.n))[4]["disturbance_torque_nm"])
    return qs, taus


def assert_same_schedules(a: list[dict], b: list[dict]) -> None:
    """Schedules equal value for value (arrays bit for bit, NaN = NaN)."""
    assert [sorted(d) for d in a] == [sorted(d) for d in b]
    for da, db in zip(a, b, strict=True):
        for key, value in da.items():
            if isinstance(value, np.ndarray):
                np.testing.assert_array_equal(value, db[key])
            else:
                assert value == db[key], key


def first_acting(taus: list[np.ndarray]) -> int:
    return next(k for k, tau in enumerate(taus) if np.any(tau))


# -- (a) home sizing: the numbers of before ---------------------------------------------

# Recorded before the sizing option existed (commit 90caf13): two-link, 100 Hz control,
# reset(seed=3), zero action, these disturbances; the torque of steps 5, 12, 25 and 59.
BEFORE_SPEC = [
    {"type": "step", "accel_rad_s2": 3.0, "onset_s": 0.2},
    {"type": "periodic", "accel_rad_s2": 2.0},
    {"type": "noise_torque", "accel_rad_s2": 1.0},
    {"type": "impulse", "accel_rad_s2": 4.0, "onset_s": 0.1, "duration_s": 0.05},
    "impulse",
]
BEFORE_TORQUES = {
    5: [-0.5793742257186713, 0.026331999377654576],
    12: [1.1340078754550973, 0.379285014948897],
    25: [-1.0188592069162916, -0.34582487923642397],
    59: [-1.6601749587217707, -0.697131494928782],
}


def test_home_sizing_gives_the_torques_of_before_bit_for_bit() -> None:
    series = {}
    for sizing in (None, "home"):
        spec = (
            BEFORE_SPEC
            if sizing is None
            else [{**s, "sizing": sizing} if isinstance(s, dict) else s for s in BEFORE_SPEC]
        )
        env = make(spec, control_hz=100.0)
        series[sizing] = np.array(run(env, 3, 60)[1])
        env.close()
    for k, tau in BEFORE_TORQUES.items():
        assert series[None][k].tolist() == tau
    assert np.array_equal(series[None], series["home"])  # default = explicit "home"


def test_home_sizing_is_the_home_mass_matrix_computed_directly() -> None:
    spec = [
        {"type": "impulse", "accel_rad_s2": ALPHA, "direction": DIRECTION, "onset_s": 0.1},
        {"type": "periodic", "accel_rad_s2": ALPHA, "direction": DIRECTION},
        {"type": "noise_torque", "accel_rad_s2": ALPHA},
    ]
    env = make(spec)
    env.reset(seed=0)
    m_home = env.model.mass_matrix(env.robot_profile.home())
    impulse, periodic, noise = env.disturbance_schedule()
    u = np.array(DIRECTION)
    assert impulse["tau_nm"].tolist() == (m_home @ (ALPHA * u)).tolist()
    assert periodic["amplitude_nm"].tolist() == np.abs(m_home @ (ALPHA * np.abs(u))).tolist()
    assert noise["std_nm"].tolist() == (ALPHA * np.diag(m_home)).tolist()
    assert {d["sizing"] for d in (impulse, periodic, noise)} == {"home"}
    env.close()


# -- (b) onset sizing: M(q) at the true state where the torque starts --------------------


def test_onset_impulse_is_the_mass_matrix_at_the_onset_state() -> None:
    spec = {
        "type": "impulse",
        "accel_rad_s2": ALPHA,
        "direction": DIRECTION,
        "onset_s": 0.1,
        "duration_s": 0.02,
        "sizing": "onset",
    }
    env = make(spec)  # 1 kHz: one sub-step per step, its q is the state before the step
    env.reset(seed=1)
    before = env.disturbance_schedule()[0]
    assert not before["sized"] and np.isnan(before["tau_nm"]).all()
    assert before["q_sized_rad"] is None
    qs, taus = run(env, 1, 130)
    k = first_acting(taus)
    q_on = qs[k]
    m_on = env.model.mass_matrix(q_on)
    expected = m_on @ (ALPHA * np.array(DIRECTION))
    np.testing.assert_allclose(taus[k], expected, rtol=1e-12)
    sched = env.disturbance_schedule()[0]
    assert sched["sized"] and sched["sizing"] == "onset"
    np.testing.assert_array_equal(sched["q_sized_rad"], q_on)
    np.testing.assert_array_equal(sched["tau_nm"], taus[k])
    np.testing.assert_array_equal(taus[k + 19], taus[k])  # held for its 20 ms, not re-sized
    assert not np.any(taus[k + 22])
    # the arm is away from home, and the sizing shows it
    home = env.robot_profile.home()
    assert abs(q_on[1] - home[1]) > 0.1  # two-link M depends on q2 only
    m_home = env.model.mass_matrix(home)
    assert np.abs(taus[k] - m_home @ (ALPHA * np.array(DIRECTION))).max() > 0.05
    env.close()


def _paired(spec: dict, seed: int, steps: int, control_hz: float = 1000.0):
    """(home run, onset run) of ``spec``, same seed: each (env, q's, torques)."""
    out = []
    for sizing in SIZINGS:
        env = make({**spec, "sizing": sizing}, control_hz=control_hz)
        qs, taus = run(env, seed, steps)
        out.append((env, qs, taus))
    return out


def test_onset_energy_impulse_gives_its_energy_at_rest_at_the_onset_configuration() -> None:
    """The impulse preset's form (energy_j): ½pᵀM(q_on)⁻¹p = E, p = τT, in the direction
    v of the home-sized impulse of the same seed (paired): M(q_on)⁻¹τ_on ∥ M_home⁻¹τ_home."""
    spec = {"type": "impulse", "energy_j": 0.4, "duration_s": 0.001, "onset_s": (0.05, 0.2)}
    for seed in (0, 5):
        (home_env, _, home_taus), (env, qs, taus) = _paired(spec, seed, 220)
        k = first_acting(taus)
        assert k == first_acting(home_taus)  # the same onset
        m_on = env.model.mass_matrix(qs[k])
        p = taus[k] * 0.001
        assert 0.5 * p @ np.linalg.solve(m_on, p) == pytest.approx(0.4, rel=1e-12)
        m_home = home_env.disturbance_context.home_mass_matrix
        v_on = np.linalg.solve(m_on, taus[k])
        v_home = np.linalg.solve(m_home, home_taus[k])
        np.testing.assert_allclose(
            v_on / np.linalg.norm(v_on), v_home / np.linalg.norm(v_home), rtol=1e-9, atol=1e-12
        )
        p_home = home_taus[k] * 0.001  # the home size: its energy at q_on is another
        assert abs(0.5 * p_home @ np.linalg.solve(m_on, p_home) - 0.4) > 0.01
        home_env.close()
        env.close()


def test_onset_step_is_m_at_onset_times_the_paired_acceleration() -> None:
    spec = {"type": "step", "accel_rad_s2": ALPHA, "onset_s": (0.05, 0.15)}
    for seed in (2, 9):
        (home_env, _, home_taus), (env, qs, taus) = _paired(spec, seed, 200)
        k = first_acting(taus)
        assert k == first_acting(home_taus)
        accel_home = np.linalg.solve(home_env.disturbance_context.home_mass_matrix, home_taus[k])
        assert np.linalg.norm(accel_home) == pytest.approx(ALPHA, rel=1e-12)  # α u, |u| = 1
        np.testing.assert_allclose(taus[k], env.model.mass_matrix(qs[k]) @ accel_home, rtol=1e-9)
        np.testing.assert_array_equal(taus[-1], taus[k])  # held to the end, not re-sized
        # home sizing misses M(q_on) α u by far more than the 1e-9 above
        assert np.abs(taus[k] - home_taus[k]).max() > 1e-3 * np.abs(taus[k]).max()
        home_env.close()
        env.close()


def test_onset_periodic_amplitude_is_fixed_from_the_start_state() -> None:
    spec = {"type": "periodic", "accel_rad_s2": ALPHA, "direction": DIRECTION}
    (home_env, _, home_taus), (env, qs, taus) = _paired(spec, 4, 300)
    home_sched, sched = home_env.disturbance_schedule()[0], env.disturbance_schedule()[0]
    q0 = qs[0]
    expected = np.abs(env.model.mass_matrix(q0) @ (ALPHA * np.abs(np.array(DIRECTION))))
    np.testing.assert_allclose(sched["amplitude_nm"], expected, rtol=1e-12)
    np.testing.assert_array_equal(sched["q_sized_rad"], q0)
    # paired: the same frequency and phases; the torque is the fixed amplitude's sine
    assert sched["frequency_hz"] == home_sched["frequency_hz"]
    np.testing.assert_array_equal(sched["phase_rad"], home_sched["phase_rad"])
    t = np.arange(300) * env.dt
    sine = np.sin(2 * np.pi * sched["frequency_hz"] * t[:, None] + sched["phase_rad"])
    np.testing.assert_allclose(np.array(taus), expected * sine, rtol=1e-9, atol=1e-12)
    home_sine = np.array(home_taus) / home_sched["amplitude_nm"]
    np.testing.assert_allclose(home_sine, sine, rtol=1e-9, atol=1e-12)
    assert np.abs(sched["amplitude_nm"] - home_sched["amplitude_nm"]).max() > 0.05
    home_env.close()
    env.close()


def test_onset_noise_std_is_diag_m_at_each_draw() -> None:
    """Paired runs: the home run's torque is α diag M(q_home) ⊙ z_k, the onset run's
    α diag M(q_k) ⊙ z_k with the same z_k and q_k its own state at each draw."""
    spec = {"type": "noise_torque", "accel_rad_s2": ALPHA, "bandwidth_hz": 5.0}
    (home_env, _, home_taus), (env, qs, taus) = _paired(spec, 6, 300)
    sigma_home = ALPHA * np.diag(home_env.disturbance_context.home_mass_matrix)
    z = np.array(home_taus) / sigma_home
    sigma = np.array([ALPHA * np.diag(env.model.mass_matrix(q)) for q in qs])
    np.testing.assert_allclose(np.array(taus), sigma * z, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(env.disturbance_schedule()[0]["std_nm"], sigma[-1])
    assert np.ptp(sigma[:, 0]) > 0.05 * sigma[0, 0]  # it follows the arm
    home_env.close()
    env.close()


def test_fraction_sizes_do_not_depend_on_the_sizing() -> None:
    spec = {"type": "impulse", "fraction": 0.2, "onset_s": 0.05, "duration_s": 0.02}
    (home_env, _, home_taus), (env, _, taus) = _paired(spec, 3, 100)
    np.testing.assert_array_equal(np.array(taus), np.array(home_taus))
    home_env.close()
    env.close()


# -- selection for a whole preset ------------------------------------------------------


def test_a_preset_is_sized_at_onset_as_a_whole() -> None:
    profile = robot_profile("iiwa")
    built = build_disturbances("mixed", profile, sizing="onset")
    sizings = {d.name: getattr(d, "sizing", None) for d in built}
    assert sizings == {
        "impulse": "onset",
        "periodic": "onset",
        "noise_torque": "onset",
        "observation_noise": None,
        "action_noise": None,
        "payload": None,
    }
    assert build_disturbances(("impulse", {"level": 0.5, "sizing": "onset"}), profile) == (
        build_disturbances(("impulse", 0.5), profile, sizing="onset")
    )
    assert build_disturbances(("periodic", {"energy_j": 2.0, "sizing": "onset"}), profile) == [
        PeriodicTorque(energy_j=2.0, sizing="onset")
    ]
    # a spec's own sizing wins over the preset-wide one
    own = build_disturbances(
        [{"type": "step", "sizing": "home"}, {"type": "step"}], profile, sizing="onset"
    )
    assert [d.sizing for d in own] == ["home", "onset"]
    assert all(
        d.sizing == "home" for d in build_disturbances("mixed", profile) if hasattr(d, "sizing")
    )


# -- (d) errors ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call",
    [
        lambda p: build_disturbances("impulse", p, sizing="start"),
        lambda p: build_disturbances(("impulse", {"sizing": "Onset"}), p),
        lambda p: build_disturbances({"type": "noise_torque", "sizing": None}, p),
        lambda p: build_disturbances(("impulse", {"level": 1.0, "energy_j": 1.0}), p),
    ],
    ids=["argument", "preset-option", "spec-field", "level-and-energy"],
)
def test_bad_sizings_raise_listing_the_choices(call) -> None:
    with pytest.raises(InvalidConfigError, match=r"'home', 'onset'|'level' or 'energy_j'"):
        call(robot_profile("two_link"))


def test_a_bad_sizing_is_refused_by_the_env() -> None:
    with pytest.raises(ValueError, match="sizing must be one of"):
        gym.make(TWO_LINK, disturbance={"type": "step", "sizing": "later"})


def _context(mass_matrix) -> DisturbanceContext:
    return DisturbanceContext(
        n=2,
        torque_limits_nm=np.ones(2),
        physics_dt_s=1e-3,
        control_dt_s=1e-3,
        horizon_s=10.0,
        ee_link="link2",
        home_mass_matrix=np.eye(2),
        ee_jacobian_home=np.zeros((3, 2)),
        mean_path_speed_rad_s=1.0,
        mass_matrix=mass_matrix,
    )


@pytest.mark.parametrize(
    "family",
    [
        ImpulseTorque(accel_rad_s2=1.0, sizing="onset"),
        ImpulseTorque(energy_j=1.0, sizing="onset"),
        StepTorque(accel_rad_s2=1.0, sizing="onset"),
        PeriodicTorque(accel_rad_s2=1.0, sizing="onset"),
        NoiseTorque(accel_rad_s2=1.0, sizing="onset"),
    ],
    ids=lambda d: d.name,
)
def test_onset_sizing_without_a_mass_matrix_is_refused_at_validation(family) -> None:
    runner = DisturbanceRunner([family], 2)
    with pytest.raises(InvalidConfigError, match=r"sizing='onset' needs .*mass matrix"):
        runner.validate(_context(None))
    runner.validate(_context(lambda q: np.eye(2)))  # with one it is accepted
    DisturbanceRunner([StepTorque(fraction=0.1, sizing="onset")], 2).validate(_context(None))


# -- (e) through gym.make: deterministic, and it survives pickling ------------------------


def test_an_onset_sized_preset_episode_is_deterministic() -> None:
    def episode(env, steps: int = 450) -> tuple[np.ndarray, list[float], list[dict]]:
        env.reset(seed=21)
        obs, rewards = [], []
        for _ in range(steps):
            o, r, terminated, _, _ = env.step(np.full(2, 0.05, dtype=np.float32))
            assert not terminated
            obs.append(o)
            rewards.append(r)
        return np.array(obs), rewards, env.unwrapped.disturbance_schedule()

    onset = ("mixed", {"sizing": "onset"})
    a = gym.make(TWO_LINK, disturbance=onset, control_hz=100.0)
    b = gym.make(TWO_LINK, disturbance=onset, control_hz=100.0)
    home = gym.make(TWO_LINK, disturbance="mixed", control_hz=100.0)
    try:
        run_a, run_b, run_home = episode(a), episode(b), episode(home)
        np.testing.assert_array_equal(run_a[0], run_b[0])
        assert run_a[1] == run_b[1]
        assert_same_schedules(run_a[2], run_b[2])
        assert all(d["sized"] for d in run_a[2] if d["type"] in ("impulse", "periodic"))
        assert not np.array_equal(run_a[0], run_home[0])  # the sizing changed the episode
        # pickled before the impulse's onset, the copy sizes it exactly as the original
        a.unwrapped.reset(seed=21)
        for _ in range(50):  # 0.5 s: the mixed impulse comes in 1-4 s
            a.unwrapped.step(np.full(2, 0.05, dtype=np.float32))
        copy = pickle.loads(pickle.dumps(a.unwrapped))
        for _ in range(400):
            o1 = a.unwrapped.step(np.full(2, 0.05, dtype=np.float32))[0]
            o2 = copy.step(np.full(2, 0.05, dtype=np.float32))[0]
            np.testing.assert_array_equal(o1, o2)
        assert_same_schedules(copy.disturbance_schedule(), run_a[2])
        copy.close()
    finally:
        for env in (a, b, home):
            env.close()


def test_the_env_argument_sizes_the_whole_disturbance() -> None:
    from ptrack_gym.envs.config import EnvConfig

    with pytest.raises(ValueError, match=r"disturbance_sizing must be one of \('home', 'onset'\)"):
        gym.make(TWO_LINK, disturbance="impulse", disturbance_sizing="later")
    config = EnvConfig(disturbance="mixed", disturbance_sizing="onset")
    assert {getattr(d, "sizing", "onset") for d in config.disturbances} == {"onset"}
    runs = []
    for kwargs in ({"disturbance_sizing": "onset"}, {"disturbance_sizing": "onset"}, {}):
        env = gym.make(TWO_LINK, disturbance="mixed", control_hz=100.0, **kwargs)
        env.reset(seed=4)
        runs.append(np.array([env.step(np.zeros(2, np.float32))[0] for _ in range(300)]))
        copy = pickle.loads(pickle.dumps(env.unwrapped))  # rebuilt from config.kwargs()
        assert copy.config.disturbance_sizing == kwargs.get("disturbance_sizing", "home")
        copy.close()
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])
