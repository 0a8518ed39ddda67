"""``train.rl.imitation``: DAgger of a model-based controller into a pure SAC actor, the pull
toward the expert's labels during RL, and their options in ``train.rl.run``."""

from __future__ import annotations

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecNormalize

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.policy import ControllerPolicy
from agents.registry import make_controller
from train.rl.config import TrainConfig, TrainConfigError, parse_args, validate
from train.rl.imitation import (
    DEMO_STATS_FILE,
    LABEL_BOUND,
    DaggerSpec,
    add_demo_bc,
    collect,
    dagger,
    demo_bc_loss,
    deterministic_action,
    load_demonstrations,
)
from train.rl.run import run

STEPS = 500  # 2-s TwoLink episodes at 250 Hz


def _env() -> gym.Env:
    return gym.make(
        "ptrack_gym/TwoLinkTrack-v0", max_episode_steps=STEPS, reward="kernel",
        max_path_distance_rad=0.5,
    )  # fmt: skip


def _model(env: gym.Env, width: int = 64) -> SAC:
    return SAC("MlpPolicy", env, policy_kwargs={"net_arch": [width, width]}, seed=0)


def _rollouts(policy: object, seeds: range) -> list[tuple[float, bool]]:
    """(path-distance RMS, ended off the path) of one undisturbed episode per seed;
    ``policy(obs, env)`` gives the action."""
    env, out = _env(), []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        d = []
        for _ in range(STEPS):
            obs, _, term, trunc, info = env.step(policy(obs, env))  # type: ignore[operator]
            d.append(info["path_distance"])
            if term or trunc:
                break
        out.append((float(np.sqrt(np.mean(np.square(d)))), bool(term)))
    return out


def _network(model: SAC):  # type: ignore[no-untyped-def]
    def act(obs: np.ndarray, env: gym.Env) -> np.ndarray:
        with torch.no_grad():
            return deterministic_action(model, torch.as_tensor(obs[None]))[0].numpy()

    return act


def _expert_rms(seeds: range) -> np.ndarray:
    experts: dict[int, ControllerPolicy] = {}

    def act(obs: np.ndarray, env: gym.Env) -> np.ndarray:
        key = id(env)
        if key not in experts:
            experts[key] = ControllerPolicy(env, make_controller("pd_gravity", env))
        return experts[key].action(obs)

    return np.array([rms for rms, _ in _rollouts(act, seeds)])


def test_collect_labels_every_state_with_the_experts_action_and_executes_the_driver() -> None:
    env = _env()
    expert = ControllerPolicy(env, make_controller("pd_gravity", env))
    # the expert drives without noise: the labels are exactly what the expert does alone
    obs, act, term = collect(env, expert, 300, 0.0, np.random.default_rng(3))
    seed = int(np.random.default_rng(3).integers(2**31 - 1))  # collect's first reset seed
    twin = _env()
    ref = ControllerPolicy(twin, make_controller("pd_gravity", twin))
    o, _ = twin.reset(seed=seed)
    for k in range(300):
        np.testing.assert_array_equal(obs[k], o)
        a = ref.action(o)
        np.testing.assert_array_equal(act[k], a)
        o, *_ = twin.step(a)
    assert term == 0
    # a driver that outputs 0: the env sees torque 0, the labels are still the expert's
    obs, act, _ = collect(env, expert, 50, 0.0, np.random.default_rng(3), lambda o: np.zeros(2))
    o, _ = twin.reset(seed=seed)
    for k in range(50):
        np.testing.assert_array_equal(obs[k], o)
        assert np.abs(act[k]).max() > 0  # the expert holds the arm up: not the zero action
        o, *_ = twin.step(np.zeros(2, dtype=np.float32))


def test_dagger_makes_a_pure_network_track_as_its_expert_and_cloning_alone_does_not() -> None:
    """The property DAgger exists for: two rounds in which the network drives and the
    expert labels bring it to its expert's path distance; cloning the expert's own runs
    alone (0 rounds) compounds its errors off the path."""
    seeds = range(50, 53)
    expert = _expert_rms(seeds)
    env = _env()
    model = _model(env)
    demos = dagger(model, env, DaggerSpec("pd_gravity", rounds=2, first_steps=10_000,
                                          round_steps=5_000), seed=0)  # fmt: skip
    assert [r.driver for r in demos.rounds] == ["expert", "network", "network"]
    assert demos.env_steps == 20_000 == len(demos.observations) == len(demos.actions)
    learned = _rollouts(_network(model), seeds)
    assert not any(off for _, off in learned)
    assert np.all(np.array([rms for rms, _ in learned]) < 2.0 * expert)

    cloned = _model(env)
    dagger(cloned, env, DaggerSpec("pd_gravity", rounds=0, first_steps=10_000), seed=0)
    only_cloned = np.array([rms for rms, _ in _rollouts(_network(cloned), seeds)])
    assert np.mean(only_cloned) > 10.0 * np.mean(expert)


def test_dagger_is_reproducible_from_its_seed() -> None:
    import random

    def once(seed: int, global_seed: int = 0) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
        env = _env()
        model = _model(env, 16)  # SB3 seeds the global generators here
        torch.manual_seed(global_seed)  # so: different global states, the same data
        np.random.seed(global_seed)  # noqa: NPY002 (the point: DAgger must not use it)
        random.seed(global_seed)
        demos = dagger(model, env, DaggerSpec("computed_torque", rounds=1, first_steps=600,
                                              round_steps=300, noise=0.01), seed=seed)  # fmt: skip
        weights = torch.cat([p.detach().flatten() for p in model.actor.parameters()])
        return demos.observations, demos.actions, weights

    a, b, c = once(4), once(4, global_seed=99), once(5)
    for x, y in zip(a[:2], b[:2], strict=True):
        np.testing.assert_array_equal(x, y)
    assert torch.equal(a[2], b[2])
    assert not np.array_equal(a[0], c[0])


def test_demo_bc_pull_moves_the_actor_toward_the_labels_and_not_while_frozen() -> None:
    env = _env()
    model = _model(env, 16)
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (64, env.observation_space.shape[0])).astype(np.float32)
    labels = np.tile(np.array([[0.3, -0.2]], dtype=np.float32), (64, 1))
    x = torch.as_tensor(obs)
    # the loss is the mean square of the distance to the labels, weighted
    got = float(demo_bc_loss(model, x, torch.as_tensor(labels), 2.0).detach())
    mu = deterministic_action(model, x).detach().numpy()
    assert got == pytest.approx(2.0 * float(np.mean((mu - labels) ** 2)), rel=1e-5)
    # labels beyond the tanh's reach are clipped as in the fit
    big = torch.full((64, 2), 3.0)
    clipped = float(demo_bc_loss(model, x, big, 1.0).detach())
    assert clipped == pytest.approx(float(np.mean((mu - LABEL_BOUND) ** 2)), rel=1e-5)

    model.batch_size = 64
    add_demo_bc(model, obs, labels, weight=1.0, seed=0)
    before = float(demo_bc_loss(model, x, torch.as_tensor(labels), 1.0).detach())
    for _ in range(50):  # the actor optimizer's steps with no other loss: the pull alone
        model.actor.optimizer.zero_grad()
        model.actor.optimizer.step()
    after = float(demo_bc_loss(model, x, torch.as_tensor(labels), 1.0).detach())
    assert after < 0.5 * before
    for p in model.actor.parameters():
        p.requires_grad_(False)
    frozen = [p.detach().clone() for p in model.actor.parameters()]
    model.actor.optimizer.zero_grad()
    model.actor.optimizer.step()
    for p, q in zip(model.actor.parameters(), frozen, strict=True):
        assert torch.equal(p.detach(), q)


def _fast(out: Path, *extra: str) -> list[str]:
    return [
        "--out", str(out), "--episode-s", "0.4", "--reward", "kernel",
        "--max-path-distance", "0.5", "--steps", "200", "--checkpoint-freq", "100",
        "--eval-freq", "0", "--imitate", "pd_gravity", "--imitate-steps", "800",
        "--imitate-round-steps", "400", "--imitate-rounds", "1",
        "--init-log-std", "-6", "--critic-warmup-steps", "100",
        "--hp", "learning_starts=0", "--hp", "batch_size=32", "--hp", "buffer_size=1000",
        "--hp", "policy_kwargs=dict(net_arch=[32, 32])", *extra,
    ]  # fmt: skip


def test_a_run_with_imitation_saves_the_demonstrations_and_the_imitation_as_step_0(
    tmp_path: Path,
) -> None:
    out = tmp_path / "r"
    result = run(parse_args(_fast(out, "--demo-bc-weight", "2")))
    assert result.num_timesteps == 200
    obs, act = load_demonstrations(out)
    assert obs.shape == (1200, 14) and act.shape == (1200, 2)
    stats = json.loads((out / DEMO_STATS_FILE).read_text())
    assert stats["env_steps"] == 1200 and [r["steps"] for r in stats["rounds"]] == [800, 400]
    assert stats["spec"]["controller"] == "pd_gravity"
    ckpt = out / "checkpoints"
    assert (ckpt / "rl_model_0_steps.zip").exists()
    assert (ckpt / "rl_model_vecnormalize_0_steps.pkl").exists()
    # the step-0 checkpoint is the imitation: it differs from the trained model's actor
    # (the pull and SAC moved it after the warm-up), and both differ from a fresh actor
    zero = SAC.load(ckpt / "rl_model_0_steps.zip", device="cpu")
    final = SAC.load(out / "model.zip", device="cpu")
    w0 = torch.cat([p.flatten() for p in zero.actor.parameters()])
    w1 = torch.cat([p.flatten() for p in final.actor.parameters()])
    assert not torch.equal(w0, w1)
    assert not torch.equal(
        w0, torch.cat([p.flatten() for p in _model(_env(), 32).actor.parameters()])
    )
    # the statistics are round 0's (the expert's 800 steps) and stay frozen through RL
    stats = [VecNormalize.load(str(ckpt / f"rl_model_vecnormalize_{k}_steps.pkl"), _dummy())
             for k in (0, 100, 200)]  # fmt: skip
    np.testing.assert_allclose(stats[0].obs_rms.mean, obs[:800].mean(0), rtol=1e-4, atol=1e-6)
    # (RunningMeanStd starts at var 1 with count 1e-4: it adds ~1e-4/800 to each variance)
    np.testing.assert_allclose(stats[0].obs_rms.var, obs[:800].var(0), rtol=1e-4, atol=1e-6)
    for later in stats[1:]:
        np.testing.assert_array_equal(later.obs_rms.mean, stats[0].obs_rms.mean)
        np.testing.assert_array_equal(later.obs_rms.var, stats[0].obs_rms.var)
    # step 0 acts as the expert labelled, through its own statistics; the frozen actor at
    # the warm-up's end (step 100) acts exactly as step 0
    x = torch.as_tensor(stats[0].normalize_obs(obs).astype(np.float32))
    with torch.no_grad():
        a0 = deterministic_action(zero, x).numpy()
        fresh = deterministic_action(_model(_env(), 32), x).numpy()
        a100 = deterministic_action(SAC.load(ckpt / "rl_model_100_steps.zip", device="cpu"), x)
    assert np.mean((a0 - act) ** 2) < 0.25 * np.mean((fresh - act) ** 2)  # measured 0.12
    np.testing.assert_array_equal(a100.numpy(), a0)


def test_resume_reapplies_the_pull_from_the_saved_demonstrations(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import train.rl.run as train_module

    out = tmp_path / "r"
    run(parse_args(_fast(out, "--demo-bc-weight", "2")))
    calls: list[tuple[int, float]] = []
    real = train_module.add_demo_bc

    def spy(model: SAC, obs: np.ndarray, act: np.ndarray, weight: float, seed: object) -> None:
        calls.append((len(obs), weight))
        real(model, obs, act, weight, seed)  # type: ignore[arg-type]

    monkeypatch.setattr(train_module, "add_demo_bc", spy)
    resumed = run(parse_args([*_fast(out, "--demo-bc-weight", "2"), "--resume"]))
    assert resumed.num_timesteps == 400
    assert calls == [(1200, 2.0)]
    # and the resumed run's statistics are still the imitation's
    first = VecNormalize.load(
        str(out / "checkpoints" / "rl_model_vecnormalize_0_steps.pkl"), _dummy()
    )
    last = VecNormalize.load(
        str(out / "checkpoints" / "rl_model_vecnormalize_400_steps.pkl"), _dummy()
    )
    np.testing.assert_array_equal(last.obs_rms.mean, first.obs_rms.mean)


def _dummy():  # type: ignore[no-untyped-def]
    from stable_baselines3.common.vec_env import DummyVecEnv

    return DummyVecEnv([_env])


@pytest.mark.parametrize(
    "fields",
    [
        {"imitate": "nope"},
        {"imitate": "pd_gravity", "residual": "passivity"},
        {"imitate": "pd_gravity", "algo": "td3"},
        {"imitate": "pd_gravity", "algo": "ppo"},
        {"imitate": "pd_gravity", "backend": "sbx"},
        {"imitate": "pd_gravity", "imitate_gains": "stiff"},
        {"imitate": "pd_gravity", "imitate_rounds": -1},
        {"imitate": "pd_gravity", "imitate_steps": 0},
        {"imitate": "pd_gravity", "imitate_round_steps": 0},
        {"imitate": "pd_gravity", "imitate_noise": float("nan")},
        {"imitate": "pd_gravity", "imitate_noise": -0.1},
        {"imitate": "pd_gravity", "demo_bc_weight": -1.0},
        {"demo_bc_weight": 1.0},
        {"imitate": "pd_gravity", "imitate_gains": "tuned", "env_id": "ptrack_gym/PandaTrack-v0"},
        {"imitate": "pd_gravity", "init_log_std": None},
        {"imitate": "pd_gravity", "overrides": {}},  # TwoLink's YAML: learning_starts 5000
        {"imitate": "pd_gravity", "overrides": {"learning_starts": 10}},
    ],
)
def test_bad_imitation_options_raise_before_anything_runs(
    tmp_path: Path, fields: dict, without_panda_gains: None
) -> None:
    ok = {"init_log_std": -6.0, "overrides": {"learning_starts": 0}}
    validate(TrainConfig(out=str(tmp_path / "ok"), imitate="pd_gravity", **ok))  # the base is fine
    with pytest.raises(TrainConfigError):
        validate(TrainConfig(out=str(tmp_path / "x"), **{**ok, **fields}))
    assert not (tmp_path / "x").exists()


def test_an_interruption_during_the_imitation_lets_the_same_command_start_over(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import train.rl.run as train_module

    out = tmp_path / "r"

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "dagger", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(parse_args(_fast(out)))
    assert not (out / "config.yml").exists()  # a fresh start is not refused
    monkeypatch.undo()
    assert run(parse_args(_fast(out))).num_timesteps == 200
    assert (out / "checkpoints" / "rl_model_0_steps.zip").exists()
