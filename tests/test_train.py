"""``ptrack train``: short SAC/TD3/PPO runs, pure and residual, in-process;
reloading, VecNormalize round-trips, resuming, and configuration errors before training.

Every run is a few hundred steps of 0.2-s TwoLink episodes with tiny networks, so the
whole file stays well under a minute on a loaded 2-core machine.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import shlex

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

from pathlib import Path

import numpy as np
import torch
import yaml
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.vec_env import VecNormalize

from train.cli import run_command as _run_command
from train.evaluation.envs import build_env
from train.evaluation.policies import ALGOS
from train.rl.actor import zero_init_actor
from train.rl.config import TrainConfig, TrainConfigError, parse_args, validate
from train.rl.hyperparameters import parse_python_literal
from train.rl.run import run

main = functools.partial(_run_command, "train")

#: Tiny, fast hyperparameters per algorithm (passed with --set).
FAST = {
    "sac": ["learning_starts=50", "batch_size=32", "buffer_size=1000"],
    "td3": ["learning_starts=50", "batch_size=32", "buffer_size=1000"],
    "ppo": ["n_steps=64", "batch_size=32", "n_epochs=2"],
}
NET = {"sac": "dict(net_arch=[32, 32])", "td3": "dict(net_arch=[32, 32])"}
NET["ppo"] = "dict(log_std_init=-1.0, net_arch=dict(pi=[32], vf=[32]), activation_fn=nn.Tanh)"


def argv(out: Path, algo: str, residual: str, steps: int, *extra: str) -> list[str]:
    """A fast command line: 0.2-s TwoLink episodes at 250 Hz (50 steps), tiny nets."""
    sets = [*FAST[algo], f"policy_kwargs={NET[algo]}"]
    return [
        "--algo",
        algo,
        "--residual",
        residual,
        "--steps",
        str(steps),
        "--out",
        str(out),
        "--episode-s",
        "0.2",
        "--eval-freq",
        "100",
        "--eval-episodes",
        "1",
        "--checkpoint-freq",
        "100",
        *[x for s in sets for x in ("--hp", s)],
        *extra,
    ]


@pytest.mark.parametrize(
    ("algo", "residual"),
    [
        ("sac", "none"),
        ("sac", "passivity"),
        ("td3", "none"),
        ("td3", "computed_torque"),
        ("ppo", "none"),
        ("ppo", "passivity"),
    ],
)
def test_short_run_saves_a_reloadable_model(tmp_path: Path, algo: str, residual: str) -> None:
    out = tmp_path / "run"
    # periodic: it acts from t = 0; an impulse (onsets 1-4 s) is refused in 0.2-s episodes
    cfg = parse_args(argv(out, algo, residual, 200, "--disturbance", "periodic:0.5"))
    result = run(cfg)
    model = result.model
    assert result.num_timesteps >= 200
    for name in ("config.yml", "command.txt", "versions.json", "model.zip", "vecnormalize.pkl"):
        assert (out / name).is_file(), name
    assert (out / "eval" / "from_0" / "evaluations.npz").is_file()
    assert (out / "checkpoints" / f"rl_model_{result.num_timesteps}_steps.zip").is_file()
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved["config"]["residual"] == residual
    assert saved["derived"]["control_hz"] == 250.0
    assert saved["derived"]["max_episode_steps"] == 50
    command = (out / "command.txt").read_text().splitlines()[-1]
    assert command.startswith("ptrack train ") and parse_args(shlex.split(command)[2:]) == cfg

    reloaded = ALGOS[algo].load(out / "model.zip", device="cpu")
    obs_dim = model.observation_space.shape[0]
    assert obs_dim == (14 if residual == "none" else reloaded.observation_space.shape[0])
    obs = np.random.default_rng(0).normal(size=(5, obs_dim)).astype(np.float32)
    a_mem, _ = model.predict(obs, deterministic=True)
    a_disk, _ = reloaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(a_mem, a_disk)

    venv = model.get_vec_normalize_env()
    assert isinstance(venv, VecNormalize)
    loaded = VecNormalize.load(str(out / "vecnormalize.pkl"), venv.venv)
    np.testing.assert_array_equal(loaded.obs_rms.mean, venv.obs_rms.mean)
    np.testing.assert_array_equal(loaded.obs_rms.var, venv.obs_rms.var)
    assert loaded.obs_rms.count == venv.obs_rms.count


def test_resume_continues_steps_replay_buffer_and_statistics(tmp_path: Path) -> None:
    """``--out RUN --resume --steps N`` alone continues the run as it was: every field not
    given is the run's (its config.yml), but the steps to add."""
    out = tmp_path / "run"
    first = run(parse_args(argv(out, "sac", "passivity", 200, "--reward", "kernel")))
    assert first.num_timesteps == 200
    count_before = first.model.get_vec_normalize_env().obs_rms.count
    resumed = parse_args(["--out", str(out), "--resume", "--steps", "200"])
    assert resumed == dataclasses.replace(first_cfg(out), resume=True, steps=200)
    second = run(resumed)
    assert second.num_timesteps == 400
    assert second.model.replay_buffer.size() == 400
    # VecNormalize continued from the checkpoint: 200 more observations (plus resets).
    assert second.model.get_vec_normalize_env().obs_rms.count > count_before + 200
    ckpt = out / "checkpoints"
    assert (ckpt / "rl_model_400_steps.zip").is_file()
    assert sorted(p.name for p in ckpt.glob("*replay_buffer*")) == [
        "rl_model_replay_buffer_400_steps.pkl"
    ]
    assert len((out / "command.txt").read_text().splitlines()) == 2
    # every given value that differs from the run's, in one error (the run's → given)
    with pytest.raises(TrainConfigError, match="3 setting") as exc:
        run(parse_args(["--out", str(out), "--resume", "--residual", "computed_torque",
                        "--reward-weights", "10", "0", "0.01", "--n-envs", "2"]))  # fmt: skip
    message = str(exc.value)
    assert "residual: 'passivity' → 'computed_torque'" in message
    assert "reward_weights: None → [10.0, 0.0, 0.01]" in message and "n_envs: 1 → 2" in message
    assert "vec_normalize" not in message
    with pytest.raises(TrainConfigError, match=r"vec_normalize: True → False"):
        run(parse_args(["--out", str(out), "--resume", "--no-vec-normalize"]))
    other = tmp_path / "other.yml"  # a config file and --set are given values too
    other.write_text("start: rest_near_path\n")
    with pytest.raises(TrainConfigError, match="2 setting") as exc:
        run(parse_args(["--out", str(out), "--resume", "--config", str(other),
                        "--set", "episode_s=0.3"]))  # fmt: skip
    assert "start: 'on_path' → 'rest_near_path'; episode_s: 0.2 → 0.3" in str(exc.value)
    hp = parse_args(["--out", str(out), "--resume", "--hp", "gamma=0.9"])
    assert hp.overrides == {**first_cfg(out).overrides, "gamma": 0.9}  # --hp over the run's
    with pytest.raises(TrainConfigError, match="overrides: "):  # the checkpoint's are loaded
        validate(hp)
    validate(parse_args(["--out", str(out), "--resume", "--hp", "n_timesteps=50"]))
    assert len((out / "command.txt").read_text().splitlines()) == 2  # refused: nothing written
    with pytest.raises(TrainConfigError, match=r"already holds a run \(400 steps\)"):
        run(parse_args(argv(out, "sac", "passivity", 100)))
    # a warm-up counts from the run's start: learning_starts 50 + 480 >= 400 done + 100
    with pytest.raises(TrainConfigError, match=r"= 530 >= the run's last step, 400 done"):
        run(parse_args(["--out", str(out), "--resume", "--steps", "100",
                        "--critic-warmup-steps", "480"]))  # fmt: skip


def first_cfg(out: Path) -> TrainConfig:
    """The config a run saved (its config.yml's ``config`` section)."""
    return TrainConfig(**yaml.safe_load((out / "config.yml").read_text())["config"])


def test_an_interrupted_run_saves_the_steps_it_took_and_resumes_from_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C (KeyboardInterrupt) 40 steps into a resumed run: model.zip and a checkpoint
    (replay buffer, statistics) at 140 — not the stale 100 of the finished run — and the
    command's status 130; --resume goes on from 140."""
    import gymnasium as gym

    import train.rl.run as tt

    out = tmp_path / "run"
    main(argv(out, "sac", "passivity", 100, "--eval-freq", "0"))
    assert SAC.load(out / "model.zip").num_timesteps == 100

    class CtrlC(gym.Wrapper):
        def step(self, action):  # type: ignore[no-untyped-def]
            self.steps = getattr(self, "steps", 0) + 1
            if self.steps == 40:
                raise KeyboardInterrupt
            return self.env.step(action)

    real = tt.build_decision_env
    monkeypatch.setattr(tt, "build_decision_env", lambda *a, **k: CtrlC(real(*a, **k)))
    assert main(argv(out, "sac", "passivity", 100, "--eval-freq", "0", "--resume")) == 130
    monkeypatch.setattr(tt, "build_decision_env", real)
    saved = SAC.load(out / "model.zip")
    assert saved.num_timesteps == 139  # the 40th step raised before it counted
    ckpt = out / "checkpoints"
    assert (ckpt / "rl_model_139_steps.zip").is_file()
    assert (ckpt / "rl_model_replay_buffer_139_steps.pkl").is_file()
    assert (ckpt / "rl_model_vecnormalize_139_steps.pkl").is_file()
    resumed = run(parse_args(argv(out, "sac", "passivity", 61, "--eval-freq", "0", "--resume")))
    assert resumed.num_timesteps == 200
    assert resumed.model.replay_buffer.size() == 200  # every counted step is in the buffer


def test_sigterm_is_an_interruption_while_a_run_trains_only() -> None:
    """Inside sigterm_as_interrupt SIGTERM raises KeyboardInterrupt (the run saves); after
    it the previous handler is back (an idle campaign worker exits quietly)."""
    import signal

    from train.common.signals import sigterm_as_interrupt

    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        signal.raise_signal(signal.SIGTERM)
    assert signal.getsignal(signal.SIGTERM) is previous
    # one-shot: a second SIGTERM while the first one's save runs is ignored
    saved = False
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        try:
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt:
            signal.raise_signal(signal.SIGTERM)  # Pool.terminate's, mid-save
            saved = True
            raise
    assert saved and signal.getsignal(signal.SIGTERM) is previous


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--hp", "learning_rat=1e-3"], "unknown hyperparameter"),
        (["--env", "ptrack_gym/NoSuchTrack-v0"], "unknown env id"),
        (["--disturbance", "earthquake"], "unknown disturbance preset"),
        (["--hp", "policy_kwargs=__import__('os').getcwd()"], "only dict"),
        (["--hp", "policy_kwargs=dict(net_arch=[os.sep])"], "not allowed"),
        (["--control-hz", "300"], "control_hz"),
        (["--reward-weights", "10", "-1", "0"], "reward_weights"),
        (["--reward-weights", "10", "nan", "0"], "reward_weights"),
        (["--resume"], "no checkpoint"),
        (["--seed", "-1"], "seed must be >= 0, got -1"),
        (["--control-hz", "0"], "control_hz must be > 0"),
        (["--episode-s", "0.001"], "less than one control step"),
        (["--device", "gpu0"], "not a torch device"),
        (["--hp", "learning_rate=-1"], "learning_rate=-1"),
        (["--hp", "train_freq=0"], "train_freq=0"),
        (["--hp", "noise_type=pink"], "noise_type must be one of"),
        (["--steps", "50"], r"learning_starts \(50\) >= the run's last step, steps \(50\)"),
        (["--critic-warmup-steps", "50"], r"learning_starts \(50\) \+ critic_warmup_steps \(50\)"),
    ],
)
def test_bad_config_raises_before_anything_is_written(
    tmp_path: Path, extra: list[str], match: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    with pytest.raises(TrainConfigError, match=match):
        run(parse_args(argv(out, "sac", "passivity", 100, *extra)))
    assert not out.exists()
    with pytest.raises(SystemExit) as exc:  # the command line: exit 2, the same message
        main(argv(out, "sac", "passivity", 100, *extra))
    assert exc.value.code == 2
    assert re.search(match, capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize("extra", [["--algo", "a2c"], ["--residual", "lqr"], ["--hp", "novalue"]])
def test_bad_cli_arguments_exit_with_usage_error(tmp_path: Path, extra: list[str]) -> None:
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(argv(out, "sac", "passivity", 100, *extra))
    assert exc.value.code == 2
    assert not out.exists()


def test_config_dataclass_is_validated_too(tmp_path: Path) -> None:
    for field, value in [("algo", "a2c"), ("residual", "lqr"), ("scale_fraction", -1.0)]:
        cfg = TrainConfig(out=str(tmp_path / "x"), **{field: value})
        with pytest.raises(TrainConfigError):
            validate(cfg)
    with pytest.raises(TrainConfigError, match="base_gains must be one of"):
        validate(TrainConfig(out=str(tmp_path / "x"), residual="passivity", base_gains="stiff"))
    res = validate(TrainConfig(out=str(tmp_path / "x"), env_id="ptrack_gym/IiwaTrack-v0"))
    assert res.control_hz == 500.0 and res.max_episode_steps == 2500
    assert res.algo_kwargs["policy_kwargs"] == {"net_arch": [400, 300]}  # the env section
    assert not (tmp_path / "x").exists()


def test_hyperparameter_file_and_set_precedence(tmp_path: Path) -> None:
    override = tmp_path / "hp.yml"
    override.write_text(
        "default:\n  gamma: 0.95\n  learning_rate: lin_1e-3\n"
        "ptrack_gym/TwoLinkTrack-v0:\n  batch_size: 128\n"
    )
    cfg = parse_args(
        ["--out", str(tmp_path / "r"), "--hyperparams", str(override), "--hp", "batch_size=64"]
    )
    res = validate(cfg)
    assert res.algo_kwargs["gamma"] == 0.95
    assert res.algo_kwargs["batch_size"] == 64
    assert res.algo_kwargs["learning_rate"](1.0) == pytest.approx(1e-3)
    assert res.algo_kwargs["learning_rate"](0.0) == 0.0
    assert res.normalize_kwargs == {"norm_obs": True, "norm_reward": False, "gamma": 0.95}
    plain = parse_args(["--out", str(tmp_path / "r2"), "--no-vec-normalize"])
    assert validate(plain).normalize_kwargs is None


def test_parse_python_literal_is_safe() -> None:
    value = parse_python_literal("dict(log_std_init=-2, net_arch=dict(pi=[64], vf=[64]))")
    assert value == {"log_std_init": -2, "net_arch": {"pi": [64], "vf": [64]}}
    assert parse_python_literal("dict(activation_fn=nn.ReLU)") == {"activation_fn": torch.nn.ReLU}
    for bad in ("open('x')", "dict(**x)", "nn.Module.__subclasses__", "[1, 2][0]", "dict(a="):
        with pytest.raises(TrainConfigError):
            parse_python_literal(bad)


@pytest.mark.parametrize("algo_cls", [SAC, TD3, PPO])
def test_zero_init_residual_starts_at_zero_action(algo_cls: type) -> None:
    env = build_env("ptrack_gym/TwoLinkTrack-v0", "passivity", 0.1, 250.0, 50, "on_path", None)
    try:
        model = algo_cls("MlpPolicy", env, seed=0, device="cpu", policy_kwargs={"net_arch": [16]})
        zero_init_actor(model)
        obs = np.random.default_rng(1).normal(size=(4, env.observation_space.shape[0]))
        action, _ = model.predict(obs.astype(np.float32), deterministic=True)
        np.testing.assert_array_equal(action, np.zeros((4, 2), dtype=np.float32))
        if algo_cls is TD3:
            with torch.no_grad():
                target = model.policy.actor_target(model.policy.obs_to_tensor(obs)[0])
            assert float(target.abs().max()) == 0.0
    finally:
        env.close()


@pytest.mark.parametrize("residual", ["none", "passivity"])
def test_env_disturbance_horizon_is_the_episode_length(residual: str) -> None:
    """Energy budgets of sustained disturbances are spread over the episode the run
    actually has (5 s at 250 Hz here), not the env's default 10-s horizon."""
    env = build_env("ptrack_gym/TwoLinkTrack-v0", residual, 0.1, 250.0, 1250, "on_path", None)
    assert env.unwrapped.disturbance_context.horizon_s == 5.0
    env.close()


def test_reward_weights_reach_the_training_env() -> None:
    """``--reward-weights`` sets the env's reward: with the time weight 0 the reward is
    −(w_path d² + w_effort |a|²/n) whatever the time-indexed error."""
    env = build_env(
        "ptrack_gym/TwoLinkTrack-v0", "passivity", 0.1, 250.0, 1250, "on_path", None,
        [10.0, 0.0, 0.01],
    )  # fmt: skip
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.full(2, 0.5, dtype=np.float32))
    assert env.unwrapped.config.reward_weights == (10.0, 0.0, 0.01)
    assert info["reward_time"] == 0.0
    assert reward == info["reward_path"] + info["reward_effort"]
    env.close()


def test_critic_warmup_freezes_the_actor_and_zero_actor_runs_the_base(tmp_path: Path) -> None:
    """With ``--zero-init-residual --freeze-actor`` the critic learns (updates are made)
    while the actor stays exactly as initialised: zero mean, the ``--init-log-std`` head;
    its deterministic actions are exactly 0, so its episode is the base controller's, bit
    for bit. A critic warm-up holds the actor so until it ends, and the run moves it after."""
    common = ["--zero-init-residual", "--init-log-std", "-3", "--hp", "learning_starts=0"]
    frozen = run(parse_args(argv(tmp_path / "f", "sac", "passivity", 120, *common,
                                 "--freeze-actor")))  # fmt: skip
    # a warm-up of 100 steps: the checkpoint at 100 is still the initial actor, the end not
    warm = run(parse_args(argv(tmp_path / "u", "sac", "passivity", 120, *common,
                               "--critic-warmup-steps", "100")))  # fmt: skip
    at_100 = SAC.load(tmp_path / "u" / "checkpoints" / "rl_model_100_steps.zip", device="cpu")
    actor = frozen.model.policy.actor
    assert frozen.model._n_updates > 0
    with torch.no_grad():
        assert float(actor.mu.weight.abs().max()) == 0.0
        assert float(actor.mu.bias.abs().max()) == 0.0
        assert float(actor.log_std.weight.abs().max()) == 0.0
        np.testing.assert_array_equal(actor.log_std.bias.numpy(), [-3.0, -3.0])
        assert float(at_100.policy.actor.mu.weight.abs().max()) == 0.0
        assert float(warm.model.policy.actor.mu.weight.abs().max()) > 0.0
    assert all(p.requires_grad for p in actor.parameters())  # released at the end

    model = SAC.load(str(tmp_path / "f" / "model.zip"), device="cpu")
    learned = build_env("ptrack_gym/TwoLinkTrack-v0", "passivity", 0.1, 250.0, 50, "on_path", None)
    base = build_env("ptrack_gym/TwoLinkTrack-v0", "passivity", 0.1, 250.0, 50, "on_path", None)
    obs, _ = learned.reset(seed=5)
    obs_base, _ = base.reset(seed=5)
    for _ in range(50):
        action, _ = model.predict(obs, deterministic=True)
        np.testing.assert_array_equal(action, np.zeros(2, dtype=np.float32))
        obs, r, *_ = learned.step(action)
        obs_base, r_base, *_ = base.step(np.zeros(2))
        np.testing.assert_array_equal(obs, obs_base)
        assert r == r_base
    learned.close()
    base.close()


def test_kernel_reward_options_reach_the_training_env(tmp_path: Path) -> None:
    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile

    res = validate(
        parse_args(argv(tmp_path / "k", "sac", "computed_torque", 100, "--reward", "kernel",
                        "--kernel-weights", "1", "0", "0", "--max-path-distance", "0.3",
                        "--action-penalty", "0.05", "--gate-rad", "0.02"))
    )  # fmt: skip
    assert res.env_extra == {
        "reward": "kernel",
        "kernel_weights": (1.0, 0.0, 0.0),
        "max_path_distance_rad": 0.3,
    }
    assert res.residual_kwargs == {
        "action_penalty": 0.05,
        "gate_rad": 0.02,
        "gate_deadband_rad": 0.0,
        "scale_accel_rad_s2": None,
        "base_gains": pinned_rates(robot_profile("two_link"), "computed_torque", "default"),
        "prior_gain_per_rad": 0.0,
        "base_model": None,
        "tank": False,
        "tank_beta": 0.5,
    }
    from train.rl.run import _env_factory

    env = _env_factory(res, "none")()
    cfg = env.unwrapped.config
    assert (cfg.reward, cfg.kernel_weights, cfg.max_path_distance_rad) == (
        "kernel", (1.0, 0.0, 0.0), 0.3,
    )  # fmt: skip
    assert (env.action_penalty, env.gate_rad) == (0.05, 0.02)
    env.close()


def test_tuned_base_gains_reach_the_training_env(tmp_path: Path) -> None:
    """--base-gains tuned: the residual corrects the base with agents/tuned's gains."""
    from agents.registry import make_controller, pinned_rates
    from ptrack_gym.robots import robot_profile
    from train.rl.run import _env_factory

    res = validate(
        parse_args(argv(tmp_path / "t", "sac", "passivity", 100, "--base-gains", "tuned"))
    )
    # pinned: the rates themselves (the tuned file's and the defaults it does not name), so
    # neither a later retune of agents/tuned nor a new default can move the base
    pinned = pinned_rates(robot_profile("two_link"), "passivity", "tuned")
    assert res.residual_kwargs["base_gains"] == pinned
    env = _env_factory(res, "none")()
    try:
        assert env.controller.gains == make_controller("passivity", env, "tuned").gains
    finally:
        env.close()


def test_a_run_pins_its_tuned_base_and_is_evaluated_and_resumed_over_it(tmp_path: Path) -> None:
    """config.yml records the tuned rates the base ran (derived.base_rates); the evaluation
    and a --resume use them, not agents/tuned's of the day."""
    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile
    from train.evaluation.envs import trained_wrapper_kwargs
    from train.rl.run import write_run_files

    out = tmp_path / "pinned"
    res = validate(parse_args(argv(out, "sac", "passivity", 100, "--base-gains", "tuned")))
    write_run_files(res, out, None)
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved["derived"]["base_rates"] == pinned_rates(
        robot_profile("two_link"), "passivity", "tuned"
    )
    # the day agents/tuned is retuned: the run keeps the rates it trained over
    older = {**saved["derived"]["base_rates"], "omega": 7.5}
    saved["derived"]["base_rates"] = older
    (out / "config.yml").write_text(yaml.safe_dump(saved, sort_keys=False))
    assert trained_wrapper_kwargs(saved)["base_gains"] == older
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "rl_model_100_steps.zip").write_bytes(b"")
    resumed = validate(
        parse_args([*argv(out, "sac", "passivity", 200, "--base-gains", "tuned"), "--resume"])
    )
    assert resumed.residual_kwargs["base_gains"] == older


def test_a_run_over_default_gains_pins_them(tmp_path: Path, monkeypatch) -> None:
    """Default gains are pinned too (every numeric rate of the day's default): the day a
    default moves, the run, its evaluation and its --resume keep the base it trained over,
    and a sweep that runs the base alone at the new default says so."""
    from agents import passivity, passivity_gains
    from agents.registry import make_controller, pinned_rates, still_pinned
    from ptrack_gym.robots import robot_profile
    from train.evaluation.envs import trained_wrapper_kwargs
    from train.rl.run import _env_factory, write_run_files

    profile = robot_profile("two_link")
    out = tmp_path / "d"
    res = validate(parse_args(argv(out, "sac", "passivity", 100)))
    write_run_files(res, out, None)
    saved = yaml.safe_load((out / "config.yml").read_text())
    pinned = saved["derived"]["base_rates"]
    assert pinned == pinned_rates(profile, "passivity", "default")
    assert "omega" in pinned and "pump" not in pinned  # the gains, not the law's choices
    assert still_pinned(profile, "passivity", "default", pinned)
    # the default moves
    now = passivity_gains.DEFAULT_RATES
    moved = {**now, "damping_ratio": now["damping_ratio"] + 0.25, "omega": 9.0}
    for where in (passivity, passivity_gains):  # the law's module re-exports the gains'
        monkeypatch.setattr(where, "DEFAULT_RATES", moved)
    assert not still_pinned(profile, "passivity", "default", pinned)
    assert trained_wrapper_kwargs(saved)["base_gains"] == pinned
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "rl_model_100_steps.zip").write_bytes(b"")
    resumed = validate(parse_args([*argv(out, "sac", "passivity", 200), "--resume"]))
    assert resumed.residual_kwargs["base_gains"] == pinned
    env = _env_factory(resumed, "none")()
    try:
        assert env.controller.gains == make_controller("passivity", env, pinned).gains
        assert env.controller.gains != make_controller("passivity", env).gains
    finally:
        env.close()
    # a pure policy has no base to pin
    assert (
        res.residual_kwargs
        and validate(parse_args(argv(tmp_path / "n", "sac", "none", 100))).residual_kwargs == {}
    )


def test_control_prior_reaches_the_training_env(tmp_path: Path) -> None:
    """--prior-gain-per-rad: the wrapper adds the stiffness prior to the learned action."""
    from train.rl.run import _env_factory

    res = validate(
        parse_args(argv(tmp_path / "p", "sac", "passivity", 100, "--prior-gain-per-rad", "1000",
                        "--scale-accel-rad-s2", "10"))
    )  # fmt: skip
    assert res.residual_kwargs["prior_gain_per_rad"] == 1000.0
    env = _env_factory(res, "none")()
    try:
        assert env.prior_gain_per_rad == 1000.0
    finally:
        env.close()


def test_acceleration_authority_reaches_the_training_env(tmp_path: Path) -> None:
    """--scale-accel-rad-s2 replaces --scale-fraction: the wrapper's residual is M(q) α a."""
    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile
    from train.rl.run import _env_factory

    res = validate(
        parse_args(argv(tmp_path / "a", "sac", "computed_torque", 100,
                        "--scale-accel-rad-s2", "10"))
    )  # fmt: skip
    assert res.residual_kwargs == {
        "action_penalty": 0.0, "gate_rad": None, "gate_deadband_rad": 0.0,
        "scale_accel_rad_s2": 10.0, "prior_gain_per_rad": 0.0,
        "base_gains": pinned_rates(robot_profile("two_link"), "computed_torque", "default"),
        "base_model": None, "tank": False, "tank_beta": 0.5,
    }  # fmt: skip
    env = _env_factory(res, "none")()
    try:
        assert env.scale_accel_rad_s2 == 10.0 and env.scale_nm is None
    finally:
        env.close()


@pytest.mark.parametrize(
    "extra",
    [
        ["--residual", "none", "--action-penalty", "0.1"],
        ["--residual", "none", "--gate-rad", "0.1"],
        ["--action-penalty", "-1"],
        ["--gate-rad", "0"],
        ["--gate-deadband-rad", "0.001"],  # a deadband without a gate
        ["--gate-rad", "0.01", "--gate-deadband-rad", "-0.001"],
        ["--residual", "none", "--gate-deadband-rad", "0.001"],
        ["--algo", "ppo", "--critic-warmup-steps", "10"],
        ["--algo", "td3", "--init-log-std", "-3"],
        ["--critic-warmup-steps", "-1"],
        ["--reward", "kernel", "--kernel-weights", "0", "0", "0"],
        ["--max-path-distance", "-0.1"],
        ["--residual", "none", "--scale-accel-rad-s2", "10"],
        ["--scale-accel-rad-s2", "-1"],
        ["--scale-accel-rad-s2", "nan"],
        ["--residual", "none", "--base-gains", "tuned"],  # a base's gains without a base
        ["--env", "ptrack_gym/PandaTrack-v0", "--base-gains", "tuned"],  # none tuned (here)
        ["--residual", "none", "--prior-gain-per-rad", "100"],  # a prior without a base
        ["--residual", "computed_torque", "--prior-gain-per-rad", "nan"],
        ["--prior-gain-per-rad", "-1"],
        ["--prior-gain-per-rad", "inf"],
    ],
)
def test_bad_safeguard_options_raise_before_anything_runs(
    tmp_path: Path, extra: list[str], without_panda_gains: None
) -> None:
    args = ["--out", str(tmp_path / "x"), "--residual", "passivity", *extra]
    with pytest.raises(TrainConfigError):
        validate(parse_args(args))
    assert not (tmp_path / "x").exists()


def test_to_argv_round_trips_every_field(tmp_path: Path) -> None:
    from train.rl.config import to_argv

    cfg = TrainConfig(
        out=str(tmp_path / "r"), algo="td3", backend="sbx", residual="computed_torque",
        scale_fraction=0.2, scale_accel_rad_s2=10.0,
        disturbance="impulse:0.5", eval_disturbance="none", steps=123, seed=7,
        overrides={"learning_starts": 0, "policy_kwargs": "dict(net_arch=[8])"}, n_envs=2,
        vec_normalize=False, eval_freq=0, checkpoint_freq=50, resume=True,
        zero_init_residual=True, control_hz=500.0, episode_s=1.5, start="rest_near_path",
        reward_weights=[1.0, 0.0, 0.5], reward="kernel", kernel_weights=[1.0, 0.0, 0.0],
        max_path_distance=0.3, action_penalty=0.05, gate_rad=0.002, gate_deadband_rad=0.001,
        base_gains="tuned", prior_gain_per_rad=100.0,
        critic_warmup_steps=10, actor_lr_scale=0.1, actor_bc_weight=0.5, torch_threads=2,
        verbose=1, imitate="pd_gravity", imitate_gains="tuned", imitate_rounds=2,
        imitate_steps=10, imitate_round_steps=5, imitate_noise=0.01, demo_bc_weight=1.5,
    )  # fmt: skip
    assert parse_args(to_argv(cfg)) == cfg
    assert parse_args(to_argv(TrainConfig(out="x"))) == TrainConfig(out="x")


def test_resume_compares_a_key_the_run_predates_with_its_default(tmp_path: Path) -> None:
    """A run written before ``decision_every`` existed ran every step: resuming it with
    another decision period is refused, as for any changed key."""
    out = tmp_path / "old"
    main(argv(out, "sac", "passivity", 60, "--eval-freq", "0"))
    cfg_file = out / "config.yml"
    saved = yaml.safe_load(cfg_file.read_text())
    del saved["config"]["decision_every"]
    cfg_file.write_text(yaml.safe_dump(saved))
    with pytest.raises(TrainConfigError, match="decision_every: 1 → 5"):
        run(parse_args(argv(out, "sac", "passivity", 100, "--eval-freq", "0", "--resume",
                            "--decision-every", "5")))  # fmt: skip


@pytest.mark.parametrize(
    ("fields", "named"),
    [
        ({"seed": -1, "n_envs": 0, "eval_freq": -1}, ["seed", "n_envs", "eval_freq"]),
        ({"eval_episodes": 0, "checkpoint_freq": -5, "torch_threads": 0},
         ["eval_episodes", "checkpoint_freq", "torch_threads"]),
        ({"steps": 0, "verbose": 3, "seed": 2**32}, ["steps", "verbose", "seed must be < 2**32"]),
        ({"episode_s": float("inf"), "control_hz": -1.0}, ["episode_s", "control_hz"]),
        ({"imitate_rounds": -1, "imitate_steps": 0, "imitate_round_steps": 0,
          "imitate_noise": -0.1}, ["imitate_rounds", "imitate_steps", "imitate_round_steps",
                                   "imitate_noise"]),
        ({"scale_fraction": float("nan"), "demo_bc_weight": -1.0, "actor_bc_weight": -1.0},
         ["scale_fraction", "demo_bc_weight", "actor_bc_weight"]),
        ({"actor_lr_scale": 0.0, "init_log_std": float("nan"), "device": "nowhere"},
         ["actor_lr_scale", "init_log_std", "device"]),
    ],
)  # fmt: skip
def test_every_number_out_of_its_domain_is_named_at_once(
    tmp_path: Path, fields: dict, named: list[str]
) -> None:
    with pytest.raises(TrainConfigError) as exc:
        validate(TrainConfig(out=str(tmp_path / "x"), **fields))
    for name in named:
        assert name in str(exc.value)
    assert not (tmp_path / "x").exists()


def test_hyperparameters_out_of_their_domain_are_named_at_once() -> None:
    from train.rl.hyperparameters import check_domains, resolve_hyperparams

    bad = {"gamma": 1.5, "tau": 0, "batch_size": 0, "buffer_size": 1.0e6, "gradient_steps": -2,
           "ent_coef": "auto_0", "learning_starts": "5000", "n_timesteps": True}  # fmt: skip
    with pytest.raises(TrainConfigError) as exc:
        check_domains(bad)
    assert all(f"{key}=" in str(exc.value) for key in bad)
    good = {"gamma": 1.0, "tau": 1, "batch_size": 1, "buffer_size": 10, "gradient_steps": -1,
            "ent_coef": "auto_0.1", "learning_starts": 0, "train_freq": (1, "episode")}  # fmt: skip
    check_domains(good)
    for text in ("lin_-1e-3", "lin_0", "lin_nan"):
        with pytest.raises(TrainConfigError, match="linear schedule"):
            resolve_hyperparams("sac", {"learning_rate": text})


def test_settings_that_contradict_each_other_are_refused(tmp_path: Path) -> None:
    """The actor must get an update before the run ends, unless --freeze-actor says it
    should not; PPO needs two samples to normalise advantages; an episodic train_freq one env."""
    out = str(tmp_path / "x")
    fast = ["--hp", "learning_starts=100"]
    with pytest.raises(TrainConfigError, match=r"learning_starts \(100\) \+ critic_warmup_steps "
                       r"\(900\) = 1000 >= the run's last step, steps \(1000\)"):  # fmt: skip
        validate(parse_args(["--out", out, "--steps", "1000", "--critic-warmup-steps", "900",
                             *fast]))  # fmt: skip
    validate(parse_args(["--out", out, "--steps", "1001", "--critic-warmup-steps", "900", *fast]))
    validate(parse_args(["--out", out, "--steps", "10", "--freeze-actor", *fast]))  # on purpose
    with pytest.raises(TrainConfigError, match="learning_starts \\(5000\\)"):  # the YAML's
        validate(parse_args(["--out", out, "--steps", "5000"]))
    for extra, match in (
        (["--algo", "ppo", "--freeze-actor"], "off-policy"),
        (["--backend", "sbx", "--freeze-actor"], "torch actor"),
        (["--algo", "ppo", "--hp", "n_steps=1"], "n_steps"),
        (["--algo", "ppo", "--hp", "batch_size=1"], "batch_size"),
        (["--n-envs", "2", "--hp", "train_freq=[1, episode]"], "needs n_envs 1"),
    ):
        with pytest.raises(TrainConfigError, match=match):
            validate(parse_args(["--out", out, *extra]))
    # a checkpoint or evaluation period beyond the run is fine (the final state is saved)
    validate(parse_args(["--out", out, "--steps", "6000", "--checkpoint-freq", "10000",
                         "--eval-freq", "10000"]))  # fmt: skip


def test_a_run_that_fails_before_its_first_step_takes_back_what_it_wrote(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A fresh run that fails before a step leaves no folder (the same command starts
    over); a resume that fails so leaves the run as it was (config.yml, command.txt, no new
    log folder); a run that failed after steps but before a checkpoint says so."""
    import gymnasium as gym

    import train.rl.run as tt

    out = tmp_path / "nested" / "run"
    cmd = argv(out, "sac", "passivity", 100, "--eval-freq", "0")

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("broken")

    monkeypatch.setattr(SAC, "_setup_learn", broken)  # inside learn, before the first step
    with pytest.raises(RuntimeError, match="broken"):
        run(parse_args(cmd))
    assert not (tmp_path / "nested").exists()
    monkeypatch.undo()
    assert run(parse_args(cmd)).num_timesteps == 100

    files = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    monkeypatch.setattr(tt, "load_checkpoint", broken)
    with pytest.raises(RuntimeError, match="broken"):
        run(parse_args(["--out", str(out), "--resume", "--steps", "60"]))
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == files
    assert not (out / "monitor" / "from_100").exists()
    monkeypatch.undo()
    assert run(parse_args(["--out", str(out), "--resume", "--steps", "60"])).num_timesteps == 160

    class Fails(gym.Wrapper):
        def step(self, action):  # type: ignore[no-untyped-def]
            self.steps = getattr(self, "steps", 0) + 1
            if self.steps == 40:
                raise RuntimeError("diverged")
            return self.env.step(action)

    real = tt.build_decision_env
    monkeypatch.setattr(tt, "build_decision_env", lambda *a, **k: Fails(real(*a, **k)))
    other = tmp_path / "other"
    with pytest.raises(RuntimeError, match="diverged"):
        run(parse_args(argv(other, "sac", "passivity", 100, "--eval-freq", "0")))
    with pytest.raises(TrainConfigError, match="stopped before its first checkpoint"):
        run(parse_args(argv(other, "sac", "passivity", 100, "--eval-freq", "0")))


def test_the_progress_bar_follows_the_terminal_unless_told(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from train.rl.run import progress_bar_on

    out = ["--out", str(tmp_path / "x")]
    assert parse_args(out).progress_bar is None
    for words, value in ((["--no-progress"], False), (["--no-progress-bar"], False),
                         (["--progress-bar"], True), (["--progress"], True)):  # fmt: skip
        assert parse_args(out + words).progress_bar is value
    for tty in (True, False):
        monkeypatch.setattr("sys.stdout.isatty", lambda tty=tty: tty)
        assert progress_bar_on(parse_args(out)) is tty
        assert progress_bar_on(parse_args([*out, "--no-progress"])) is False
        assert progress_bar_on(parse_args([*out, "--progress"])) is True


def test_training_and_evaluation_paths_are_declared_pools(tmp_path: Path) -> None:
    """--train-paths: the training env draws one of those random paths per episode;
    --eval-paths: the evaluation env holds out others; both are in the run's config."""
    from train.rl.run import _env_factory

    out = tmp_path / "paths"
    run(parse_args(argv(out, "sac", "passivity", 100, "--train-paths", "11", "12",
                        "--eval-paths", "21")))  # fmt: skip
    saved = yaml.safe_load((out / "config.yml").read_text())
    saved = saved.get("config", saved)
    assert saved["train_paths"] == [11, 12] and saved["eval_paths"] == [21]
    res = validate(parse_args(argv(tmp_path / "v", "sac", "passivity", 100, "--train-paths",
                                   "11", "12", "--eval-paths", "21")))  # fmt: skip
    train_env = _env_factory(res, "none", res.cfg.train_paths)()
    seen = {train_env.reset(seed=s)[1]["path_seed"] for s in range(12)}
    assert seen == {11, 12}
    train_env.close()


def test_training_and_evaluation_families_are_declared_choices(tmp_path: Path) -> None:
    """--train-families: one of those disturbances per training episode; --eval-families:
    held-out ones for the evaluation env; both in the run's config."""
    from train.rl.run import _env_factory

    extra = ["--train-families", "impulse:0.5", "periodic", "--eval-families", "push",
             "--episode-s", "5.0"]  # fmt: skip
    res = validate(parse_args(argv(tmp_path / "v", "sac", "none", 100, *extra)))
    assert res.cfg.train_families == ["impulse:0.5", "periodic"]
    env = _env_factory(res, "none", None, res.cfg.train_families)()
    seen = {env.reset(seed=s)[1]["disturbance_choice"] for s in range(12)}
    assert seen == {0, 1}
    assert env.unwrapped.config.disturbance_choices == (("impulse", 0.5), "periodic")
    env.close()


def test_randomized_masses_scale_every_link_per_training_episode(tmp_path: Path) -> None:
    """--randomize-mass 0.1: each link's mass within ±10 % of nominal, redrawn per episode,
    on top of each training family; the evaluation env stays nominal."""
    from train.rl.run import _env_factory

    extra = ["--train-families", "impulse", "periodic", "--randomize-mass", "0.1",
             "--episode-s", "5.0"]  # fmt: skip
    res = validate(parse_args(argv(tmp_path / "v", "sac", "none", 100, *extra)))
    env = _env_factory(res, "none", None, res.cfg.train_families, res.cfg.randomize_mass)()
    u = env.unwrapped
    draws = []
    for s in range(6):
        env.reset(seed=s)
        assert [type(d).__name__ for d in u.runner.items][-1] == "Mismatch"
        draws.append(u.disturbance_schedule()[-1])
    scales = u.runner.items[-1]._scales
    assert set(scales) == {"link1", "link2"} and all(0.9 <= v <= 1.1 for v in scales.values())
    assert len({str(d) for d in draws}) == 6  # redrawn every episode
    env.close()
    nominal = _env_factory(res, "none", None, ["push"])()  # an evaluation env's arguments
    assert all(type(d).__name__ != "Mismatch" for d in nominal.unwrapped.runner.items)
    nominal.close()


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--randomize-mass", "1.0"], r"randomize_mass must be in \[0, 1\)"),
        (
            ["--train-families", "impulse", "noise", "--eval-families", "noise:2"],
            r"eval_families \['noise'\] are training families",
        ),
        (["--train-families", "impulse", "--disturbance", "noise"], "leave disturbance 'none'"),
        (["--train-families", "hurricane"], "unknown disturbance preset"),
        (["--train-paths", "1", "2", "--eval-paths", "2", "3"], r"eval_paths \[2\] are training"),
        (["--eval-paths", "3"], "give train_paths"),
        (["--train-paths", "1", "1"], "train_paths must be distinct"),
        (
            ["--train-paths", "1", "2", "--imitate", "pd_gravity", "--init-log-std", "-1"],
            "imitate over a pool",
        ),
    ],
)
def test_bad_path_splits_raise_before_anything_is_written(
    tmp_path: Path, extra: list[str], match: str
) -> None:
    out = tmp_path / "run"
    residual = "none" if "--imitate" in extra else "passivity"  # imitation: pure SAC only
    with pytest.raises(TrainConfigError, match=match):
        run(parse_args(argv(out, "sac", residual, 100, *extra)))
    assert not out.exists()


def test_a_residual_run_without_a_complete_pin_warns_when_evaluated(tmp_path: Path) -> None:
    """A run written before pins (or pinning some rates only) is evaluated over today's
    rates for what it did not pin: said, not silent; a complete pin is silent."""
    import warnings

    from train.evaluation.envs import trained_wrapper_kwargs
    from train.rl.run import write_run_files

    out = tmp_path / "r"
    write_run_files(validate(parse_args(argv(out, "sac", "passivity", 100))), out, None)
    saved = yaml.safe_load((out / "config.yml").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        trained_wrapper_kwargs(saved)
    partial = {**saved, "derived": {**saved["derived"], "base_rates": {"omega": 20.0}}}
    with pytest.warns(UserWarning, match="pinned only some of its base's rates"):
        assert trained_wrapper_kwargs(partial)["base_gains"] == {"omega": 20.0}
    none = {**saved, "derived": {**saved["derived"], "base_rates": None}}
    with pytest.warns(UserWarning, match="recorded no rates for its base"):
        assert trained_wrapper_kwargs(none)["base_gains"] == "default"
