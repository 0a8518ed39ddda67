"""Disturbances: physical effect of each family, seeded pairing, the energy ledger with
the passivity controller, sensing, presets and levels, energy budgets, bad specs."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from passivity_energy import run_passivity_energy

import ptrack_gym  # noqa: F401  (registers the envs)
from ptrack_gym.disturbances import (
    PRESETS,
    Disturbance,
    build_disturbances,
)
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel, TwoLinkParams
from ptrack_gym.sim import BulletSim

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
HOLD_Q = np.array([0.3, -0.5])


def make(disturbance, **kwargs):
    return gym.make(TWO_LINK, disturbance=disturbance, **kwargs).unwrapped


def hold_action(env, q):
    """The normalized action holding pose q against the nominal gravity."""
    return env.model.gravity(q) / env.torque_limits_nm


def momentum(env):
    q, qd = env.joint_state()
    return env.model.mass_matrix(q) @ qd


def test_impulse_changes_generalized_momentum_by_its_size() -> None:
    """Two paired runs from rest, same constant action: right after a 20 ms joint-torque
    impulse τ_d the momentum M q̇ differs by τ_d · T (gravity and Coriolis terms, equal in
    both runs to first order, cancel)."""
    spec = {"type": "impulse", "fraction": 0.3, "duration_s": 0.02, "onset_s": 0.1}
    runs = []
    for disturbance in (None, spec):
        env = make(disturbance)
        env.reset(seed=1, options={"q": HOLD_Q, "qd": np.zeros(2)})
        a = hold_action(env, HOLD_Q)
        for _ in range(120):  # 0.12 s: the impulse ran during [0.1, 0.12)
            env.step(a)
        runs.append((momentum(env), env.disturbance_schedule()))
        env.close()
    (p0, _), (p1, sched) = runs
    expected = sched[0]["tau_nm"] * 0.02
    np.testing.assert_allclose(p1 - p0, expected, rtol=0.02, atol=1e-3 * np.abs(expected).max())
    assert np.abs(expected).max() > 0.1  # not vacuous


def test_payload_changes_the_holding_torque_by_m_g_lever_arm() -> None:
    """At rest, the torque that holds the arm with a point mass m at the tip is the nominal
    gravity plus m·g·(x_tip, x_tip − x_elbow): with it the arm stays still, without it moves."""
    mass = 0.7
    params = TwoLinkParams()
    fk = TwoLinkAnalyticModel(params)
    x_tip = fk.ee_position(HOLD_Q)[0]
    lever = np.array([x_tip, params.l2_m * np.cos(HOLD_Q.sum())])
    env = make({"type": "payload", "mass_kg": mass})
    results = []
    for extra in (mass * 9.81 * lever, np.zeros(2)):
        env.reset(seed=0, options={"q": HOLD_Q, "qd": np.zeros(2)})
        assert env.arm.link_mass("tip") == pytest.approx(mass)
        env.step((env.model.gravity(HOLD_Q) + extra) / env.torque_limits_nm)
        results.append(np.abs(env.joint_state()[1]).max())
    held, dropped = results
    assert held < 1e-9
    assert dropped > 1e-3
    # The nominal model never sees the payload.
    np.testing.assert_allclose(env.model.gravity(HOLD_Q), fk.gravity(HOLD_Q), atol=1e-12)
    env.close()


def test_payload_is_picked_up_and_dropped_mid_episode() -> None:
    env = make({"type": "payload", "mass_kg": 0.5, "pick_s": 0.05, "drop_s": 0.1}, control_hz=100)
    env.reset(seed=0)
    masses = []
    for _ in range(15):
        env.step(np.zeros(2))  # applies the plant as it is at the step's start time
        masses.append(env.arm.link_mass("tip"))
    # Control steps start at t = 0, 0.01, ...: held for t in [0.05, 0.1).
    assert masses == [0.0] * 5 + [0.5] * 5 + [0.0] * 5
    env.reset(seed=1)
    assert env.arm.link_mass("tip") == 0.0  # restored at reset
    env.close()


def test_the_plant_is_recomputed_only_when_an_editor_changes_it(monkeypatch) -> None:
    spec = [
        {"type": "payload", "mass_kg": 0.5, "pick_s": 0.05, "drop_s": 0.1},
        {"type": "mismatch", "mass_scale": 1.1, "links": ["link1"]},
    ]
    action = np.array([0.1, -0.2])

    def run(env) -> tuple[np.ndarray, int]:
        calls = []
        set_mass_changes = env.arm.set_mass_changes
        monkeypatch.setattr(
            env.arm, "set_mass_changes", lambda ch: (calls.append(ch), set_mass_changes(ch))
        )
        env.reset(seed=0)
        qs = [env.step(action)[0] for _ in range(15)]
        return np.array(qs), len(calls)

    lazy = make(spec, control_hz=100)
    eager = make(spec, control_hz=100)  # told that its editors may change at any time
    for d in eager.runner.items:
        monkeypatch.setattr(d, "plant_change_times", lambda: None)
    try:
        q_lazy, n_lazy = run(lazy)
        q_eager, n_eager = run(eager)
        assert n_lazy == 3 and n_eager == 16  # reset, pick-up, drop; vs. every step
        assert np.array_equal(q_lazy, q_eager)  # the same plant at every step
        # unpickled mid-hold, the rebuilt (nominal) body gets the payload back
        lazy.reset(seed=0)
        for _ in range(7):
            lazy.step(action)
        copy = pickle.loads(pickle.dumps(lazy))
        assert copy.arm.link_mass("tip") == 0.5
        assert np.array_equal(copy.step(action)[0], lazy.step(action)[0])
        copy.close()
    finally:
        lazy.close()
        eager.close()


def test_periodic_disturbance_has_its_stated_frequency() -> None:
    env = make({"type": "periodic", "fraction": 0.1, "frequency_hz": (0.5, 2.0)}, control_hz=100)
    env.reset(seed=4)
    sched = env.disturbance_schedule()[0]
    taus, times = [], []
    for _ in range(800):
        t = env.t
        _, _, terminated, _, info = env.step(hold_action(env, env.joint_state()[0]))
        assert not terminated
        taus.append(info["disturbance_torque_nm"])
        times.append(t + env.dt - env.physics_dt)  # start time of the last sub-step
    taus, times = np.array(taus), np.array(times)
    expected = sched["amplitude_nm"] * np.sin(
        2 * np.pi * sched["frequency_hz"] * times[:, None] + sched["phase_rad"]
    )
    np.testing.assert_allclose(taus, expected, atol=1e-12)
    spectrum = np.abs(np.fft.rfft(taus[:, 0] - taus[:, 0].mean()))
    freqs = np.fft.rfftfreq(len(times), d=0.01)
    assert abs(freqs[np.argmax(spectrum)] - sched["frequency_hz"]) <= freqs[1]
    env.close()


class _EquivalentTorque(Disturbance):
    """Test double: the joint torque Jᵀ(q) F that a push F at the tip is equivalent to."""

    name = "equivalent"

    def __init__(self, kinematics, force, onset, duration):
        self.kinematics, self.force, self.onset, self.duration = kinematics, force, onset, duration

    def joint_torque(self, t_s, q, qd):
        if self.onset <= t_s < self.onset + self.duration:
            return self.kinematics.com_jacobian("tip", q).T @ self.force
        return None


def test_push_acts_as_the_equivalent_joint_torque() -> None:
    """A world-frame force at the tip moves the arm exactly like the joint torque JᵀF
    (the frame and point of application are right), and the ledger sees the same work."""
    push = {"type": "push", "force_n": 15.0, "duration_s": 0.05, "onset_s": 0.02}
    env = make(push)
    env.reset(seed=2, options={"q": HOLD_Q, "qd": np.zeros(2)})
    force = env.disturbance_schedule()[0]["force_n"]
    with BulletSim() as sim:  # an independent copy of the arm for the Jacobian
        spec = robot_profile("two_link")
        kinematics = sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)
        twin = make([_EquivalentTorque(kinematics, force, 0.02, 0.05)])
        twin.reset(seed=2, options={"q": HOLD_Q, "qd": np.zeros(2)})
        a = hold_action(env, HOLD_Q)
        for _ in range(100):
            _, _, _, _, info = env.step(a)
            _, _, _, _, info_twin = twin.step(a)
    np.testing.assert_allclose(env.joint_state()[0], twin.joint_state()[0], atol=1e-6)
    assert info["disturbance_work_j"] == pytest.approx(info_twin["disturbance_work_j"], rel=1e-3)
    assert abs(info["disturbance_work_j"]) > 1e-3
    env.close()
    twin.close()


def _torque_series(env, seed, actions):
    env.reset(seed=seed)
    out = []
    for a in actions:
        out.append(env.step(a)[4]["disturbance_torque_nm"])
    return env.disturbance_schedule(), np.array(out)


def test_same_seed_same_schedule_whatever_the_actions() -> None:
    env = make(["impulse", "periodic", {"type": "noise_torque", "fraction": 0.05}], control_hz=100)
    rng = np.random.default_rng(0)
    acts_a = rng.uniform(-0.2, 0.2, (300, 2))
    acts_b = np.zeros((300, 2))
    sched_a, tau_a = _torque_series(env, 11, acts_a)
    sched_b, tau_b = _torque_series(env, 11, acts_b)
    sched_c, tau_c = _torque_series(env, 12, acts_a)
    assert pickle.dumps(sched_a) == pickle.dumps(sched_b)
    np.testing.assert_array_equal(tau_a, tau_b)  # bit-identical
    assert pickle.dumps(sched_a) != pickle.dumps(sched_c)
    assert not np.array_equal(tau_a, tau_c)
    env.close()


def test_disturbances_do_not_change_the_start_state() -> None:
    """The start state comes from its own stream: adding disturbances does not move it."""
    plain, disturbed = make(None), make("mixed")
    for seed in (0, 5):
        o1, _ = plain.reset(seed=seed)
        o2, _ = disturbed.reset(seed=seed)
        np.testing.assert_array_equal(plain.joint_state()[0], disturbed.joint_state()[0])
        np.testing.assert_array_equal(o1[4:8], o2[4:8])  # reference part
    plain.close()
    disturbed.close()


def test_energy_ledger_balances_with_the_passivity_controller() -> None:
    """E(T) − E(0) = −∫R s̃̇² + ∫pump power + ∫q̇ᵀτ_d: within 1% of the energy flows at 1 kHz
    (measured 0.2%), the error shrinking with the time step (first-order scheme)."""
    disturbance = [
        {"type": "impulse", "fraction": 0.2, "duration_s": 0.05, "onset_s": 0.3},
        {"type": "periodic", "fraction": 0.05},
    ]
    run1 = run_passivity_energy(1000.0, k_pump=2.0, disturbance=disturbance)
    run4 = run_passivity_energy(4000.0, k_pump=2.0, disturbance=disturbance)
    assert not (run1.saturated or run4.saturated)  # no clipping: premise
    flows1 = abs(run1.work) + run1.dissipated + abs(run1.pumped)
    assert flows1 > 0.1
    assert abs(run1.mismatch) < 0.01 * flows1
    assert abs(run4.mismatch) < abs(run1.mismatch) / 2.0


def test_observation_noise_and_delay_change_what_is_seen_not_the_plant() -> None:
    clean = make(None, control_hz=100)
    noisy = make(
        {"type": "observation_noise", "q_std_rad": 0.01, "qd_std_rad_s": 0.1}, control_hz=100
    )
    delayed = make({"type": "observation_delay", "steps": 3}, control_hz=100)
    for env in (clean, noisy, delayed):
        env.reset(seed=3)
    history = []
    for _ in range(6):
        outs = [env.step(np.full(2, 0.1)) for env in (clean, noisy, delayed)]
        history.append(clean.joint_state()[0])
        # The plants move identically: sensing does not act on them.
        np.testing.assert_array_equal(clean.joint_state()[0], noisy.joint_state()[0])
        np.testing.assert_array_equal(clean.joint_state()[0], delayed.joint_state()[0])
    obs_noisy = outs[1][0]
    assert 1e-4 < np.abs(obs_noisy[:2] - clean.joint_state()[0]).max() < 0.1
    np.testing.assert_array_equal(delayed.measured_joint_state()[0], history[-4])
    for env in (clean, noisy, delayed):
        env.close()


def test_action_noise_and_mismatch_act_on_the_plant() -> None:
    env = make({"type": "action_noise", "fraction": 0.05})
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2))
    assert 0 < np.abs(info["disturbance_torque_nm"]).max() < 0.5 * env.torque_limits_nm.max()
    env.close()
    env = make(("mismatch", 1.0))
    env.reset(seed=0)
    scales = env.disturbance_schedule()[0]["mass_scales"]
    assert env.arm.link_mass("link1") == pytest.approx(2.0 * scales["link1"])
    assert not np.isclose(scales["link1"], 1.0)
    work = 0.0
    for _ in range(300):
        _, _, _, _, info = env.step(np.full(2, 0.2))
        work = info["disturbance_work_j"]
    assert work < 0  # damping and friction only take energy out
    env.close()


@pytest.mark.parametrize(
    ("control_hz", "level", "steps"),
    [(1000, 0.5, 1), (1000, 1.0, 2), (1000, 2.0, 4), (500, 1.0, 1), (500, 2.0, 2),
     (250, 1.0, 1), (250, 2.0, 1), (100, 2.0, 1)],
)  # fmt: skip
def test_delay_preset_reports_the_newest_sample_at_least_2ms_x_level_old(
    control_hz, level, steps
) -> None:
    delayed, clean = (
        make(("delay", level), control_hz=control_hz),
        make(None, control_hz=control_hz),
    )
    delayed.reset(seed=4)
    clean.reset(seed=4)
    history = [clean.joint_state()]
    for _ in range(8):
        for env in (delayed, clean):
            env.step(np.full(2, 0.2))
        history.append(clean.joint_state())
        np.testing.assert_array_equal(delayed.joint_state()[0], clean.joint_state()[0])
        seen = delayed.measured_joint_state()
        for got, want in zip(seen, history[max(0, len(history) - 1 - steps)], strict=True):
            np.testing.assert_array_equal(got, want)
    # the sample is at least the preset's delay old, and less than one control step older
    assert steps / control_hz >= 2e-3 * level - 1e-12
    assert (steps - 1) / control_hz < 2e-3 * level


def test_the_friction_preset_only_takes_energy_and_more_at_a_higher_level() -> None:
    """Damping and Coulomb friction oppose q̇ joint by joint: their work on the arm is
    negative at every sub-step, so over an episode; twice the level takes more."""
    from train.evaluation.episode import EpisodeSettings, Task, run_episode

    settings = EpisodeSettings("ptrack_gym/TwoLinkTrack-v0", 2.0, 250.0, "on_path", 0.5, 0.01)
    work = [
        run_episode(Task("pd_gravity", "friction", level, 0, 0), settings)[0]
        for level in (1.0, 2.0)
    ]
    assert work[0]["disturbance_work_j"] < 0.0
    assert work[1]["disturbance_work_j"] < work[0]["disturbance_work_j"]
    built = build_disturbances(("friction", 1.0), robot_profile("iiwa"))
    assert [d.name for d in built] == ["mismatch"] and built[0].links == ()


def test_level_zero_is_no_disturbance_and_presets_build() -> None:
    for name in PRESETS:
        assert build_disturbances((name, 0.0), robot_profile("iiwa")) == []
        built = build_disturbances((name, 1.0), robot_profile("iiwa"))
        assert (name == "none") == (built == [])
    a, b = make(("impulse", 0.0)), make(None)
    a.reset(seed=1)
    b.reset(seed=1)
    for _ in range(50):
        oa, _ra, *_ = a.step(np.full(2, 0.3))
        ob, _rb, *_ = b.step(np.full(2, 0.3))
    np.testing.assert_array_equal(oa, ob)
    a.close()
    b.close()


def test_energy_budget_sets_the_impulse_size() -> None:
    env = make(("impulse", {"energy_j": 0.8}))
    env.reset(seed=0)
    sched = env.disturbance_schedule()[0]
    p = sched["tau_nm"] * sched["duration_s"]
    m_home = env.disturbance_context.home_mass_matrix
    assert 0.5 * p @ np.linalg.solve(m_home, p) == pytest.approx(0.8, rel=1e-12)
    env.close()


def _kinetic_energy_jump(
    mode: str, onset_s: float, direction: list[float], family: str = "impulse"
) -> tuple[float, float]:
    """What an impulse (or a push at the end effector) of 0.3 J does in its one physics
    step to the falling two-link arm (zero action from the path): the kinetic energy it
    adds, T(q̇⁺) with it − T(q̇⁺) without (both in the M(q) of the step: PyBullet's step is
    semi-implicit Euler with that M), and the part of it that gravity's pull during the step
    adds, pᵀ(q̇₀⁺ − q̇), p the joint momentum and q̇₀⁺ the velocity after the step without it."""
    spec = {"type": family, "energy_j": 0.3, "duration_s": 0.001, "onset_s": onset_s,
            "direction": direction, "energy_mode": mode}  # fmt: skip
    envs = [gym.make(TWO_LINK, disturbance=d, control_hz=1000.0) for d in (spec, None)]
    try:
        for e in envs:
            e.reset(seed=3)
        zero = np.zeros(2, dtype=np.float32)
        while True:
            q_pre, qd_pre = envs[0].unwrapped.joint_state()
            infos = [e.step(zero)[-1] for e in envs]
            if np.any(infos[0]["disturbance_torque_nm"]):
                break
        m = envs[0].unwrapped.model.mass_matrix(q_pre)
        qd_with, qd_without = (e.unwrapped.joint_state()[1] for e in envs)
        p = infos[0]["disturbance_torque_nm"] * 0.001
        jump = 0.5 * qd_with @ m @ qd_with - 0.5 * qd_without @ m @ qd_without
        return jump, float(p @ (qd_without - qd_pre))
    finally:
        for e in envs:
            e.close()


def test_delivered_mode_gives_the_moving_arm_its_energy_budget() -> None:
    rng = np.random.default_rng(0)
    home = []
    for _ in range(6):
        onset, direction = float(rng.uniform(0.2, 0.8)), rng.normal(size=2).tolist()
        jump, gravity_part = _kinetic_energy_jump("delivered", onset, direction)
        # the sizing solves pᵀq̇ + ½pᵀM⁻¹p = E at the onset state: exact, but for what
        # gravity adds while the impulse acts
        assert jump - gravity_part == pytest.approx(0.3, rel=1e-9)
        assert abs(gravity_part) < 0.15 * 0.3
        home.append(_kinetic_energy_jump("home", onset, direction)[0])
    assert np.ptp(home) > 0.1  # sized at rest at home, it gives the moving arm other energies


def test_a_delivered_push_gives_the_moving_arm_its_energy_budget() -> None:
    """The push's joint momentum p = J(q)ᵀF·T, sized at its onset from (q, q̇): the same
    budget as an impulse's (the two-link moves in the x-z plane: world directions in it)."""
    rng = np.random.default_rng(1)
    home = []
    for _ in range(6):
        onset = float(rng.uniform(0.2, 0.8))
        angle = float(rng.uniform(0.0, 2.0 * np.pi))
        direction = [float(np.cos(angle)), 0.0, float(np.sin(angle))]
        jump, gravity_part = _kinetic_energy_jump("delivered", onset, direction, "push")
        assert jump - gravity_part == pytest.approx(0.3, rel=1e-6)
        home.append(_kinetic_energy_jump("home", onset, direction, "push")[0])
    assert np.ptp(home) > 0.05  # sized at rest at home, the push gives other energies


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ({"type": "impulse", "fracton": 0.2}, "fracton"),
        ({"type": "nope"}, "type"),
        ({"fraction": 0.2}, "type"),
        ("hurricane", "unknown disturbance preset"),
        (("impulse", -1.0), "level"),
        (("payload", {"energy_j": 1.0}), "energy budget"),
        (("impulse", {"energy": 1.0}), "energy_j"),
        ({"type": "impulse", "fraction": -0.2}, "fraction"),
        ({"type": "observation_delay", "steps": 1.5}, "steps"),
        ({"type": "observation_delay", "steps": True}, "steps"),
        ({"type": "observation_delay", "delay_s": -1e-3}, "delay_s"),
        ({"type": "observation_delay", "steps": 2, "delay_s": 2e-3}, "not both"),
        ({"type": "push", "energy_mode": "delivered"}, "needs energy_j"),
        ({"type": "push", "energy_j": 1.0, "energy_mode": "kinetic"}, "energy_mode"),
        (42, "cannot build"),
    ],
)
def test_bad_specs_raise_clear_errors(spec, match) -> None:
    with pytest.raises(InvalidConfigError, match=match):
        build_disturbances(spec, robot_profile("two_link"))
    with pytest.raises(ValueError, match=match):
        gym.make(TWO_LINK, disturbance=spec)


@pytest.mark.parametrize(
    "disturbance",
    [
        "mixed",
        # sized at its onset (1.5 s), after the pickle: the copy re-attaches M(q) and J(q)
        {"type": "push", "energy_j": 0.3, "onset_s": 1.5, "energy_mode": "delivered"},
    ],
)
def test_disturbed_env_pickles_and_continues_identically(disturbance) -> None:
    env = make(disturbance, control_hz=100)
    env.reset(seed=9)
    for _ in range(250):  # past the payload pick-up window start
        env.step(np.full(2, 0.05))
    copy = pickle.loads(pickle.dumps(env))
    for _ in range(100):
        o1, r1, *_ = env.step(np.full(2, 0.05))
        o2, r2, *_ = copy.step(np.full(2, 0.05))
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2
    env.close()
    copy.close()
