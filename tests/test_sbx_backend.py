"""``--backend sbx``: the SB3 team's JAX port behind the same CLI, config and run files —
a short run saves, reloads with identical actions (as the evaluation loads it), resumes;
the torch-only safeguards and a missing extra are refused before anything runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

from train.rl.config import TrainConfigError, parse_args, validate
from train.rl.run import run

FAST = [
    "learning_starts=50",
    "batch_size=32",
    "buffer_size=1000",
    "policy_kwargs=dict(net_arch=[32, 32])",
]


def argv(out: Path, algo: str, residual: str, steps: int, *extra: str) -> list[str]:
    """0.2-s TwoLink episodes at 250 Hz (50 steps), tiny nets, the sbx backend."""
    sets = [x for s in FAST for x in ("--hp", s)]
    return [
        "--backend", "sbx", "--algo", algo, "--residual", residual, "--steps", str(steps),
        "--out", str(out), "--episode-s", "0.2", "--eval-freq", "100", "--eval-episodes", "1",
        "--checkpoint-freq", "100", *sets, *extra,
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("algo", "residual"),
    [("sac", "none"), pytest.param("td3", "passivity", marks=pytest.mark.slow)],
)  # the second: another algorithm and a residual through the same code (make test-slow)
def test_sbx_run_saves_reloads_as_the_evaluation_does_and_resumes(
    tmp_path: Path, algo: str, residual: str
) -> None:
    sbx = pytest.importorskip("sbx", reason="the optional 'sbx' extra (sbx-rl, JAX)")
    from train.evaluation.policies import load_sb3_policy

    out = tmp_path / "run"
    # periodic: it acts from t = 0; an impulse (onsets 1-4 s) is refused in 0.2-s episodes
    first = run(parse_args(argv(out, algo, residual, 200, "--disturbance", "periodic:0.5")))
    assert isinstance(first.model, {"sac": sbx.SAC, "td3": sbx.TD3}[algo])
    assert first.num_timesteps == 200
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved["config"]["backend"] == "sbx"
    assert "jax" in (out / "versions.json").read_text()
    assert (out / "eval" / "from_0" / "evaluations.npz").is_file()

    # The evaluation's loader: the run's sbx class, its VecNormalize statistics first.
    policy, _ = load_sb3_policy(f"sb3:{out}", "ptrack_gym/TwoLinkTrack-v0")
    assert type(policy.model) is type(first.model)
    venv = first.model.get_vec_normalize_env()
    dim = first.model.observation_space.shape[0]
    obs = np.random.default_rng(0).normal(size=(5, dim)).astype(np.float32)
    a_mem, _ = first.model.predict(venv.normalize_obs(obs), deterministic=True)
    a_disk, _ = policy.predict(obs)
    np.testing.assert_array_equal(a_mem, a_disk)

    second = run(parse_args(argv(out, algo, residual, 100, "--disturbance", "periodic:0.5",
                                 "--resume")))  # fmt: skip
    assert second.num_timesteps == 300
    assert second.model.replay_buffer.size() == 300
    with pytest.raises(TrainConfigError, match="backend"):  # resumed by the other backend
        cli = argv(out, algo, residual, 100, "--disturbance", "periodic:0.5", "--resume")
        run(parse_args([a if a != "sbx" else "sb3" for a in cli]))


@pytest.mark.parametrize(
    "extra",
    [["--zero-init-residual"], ["--init-log-std", "-3"], ["--critic-warmup-steps", "100"]],
)
def test_sbx_refuses_the_torch_only_safeguards(tmp_path: Path, extra: list[str]) -> None:
    args = argv(tmp_path / "x", "sac", "passivity", 100, *extra)
    with pytest.raises(TrainConfigError, match="backend 'sbx'"):
        validate(parse_args(args))
    assert not (tmp_path / "x").exists()


def test_sbx_without_its_extra_is_named_before_anything_runs(tmp_path: Path, monkeypatch) -> None:
    import train.evaluation.policies

    monkeypatch.setattr(train.evaluation.policies, "sbx_available", lambda: False)
    with pytest.raises(TrainConfigError, match="'sbx' extra"):
        validate(parse_args(argv(tmp_path / "x", "sac", "none", 100)))
    assert not (tmp_path / "x").exists()


def test_unknown_backend_is_refused(tmp_path: Path) -> None:
    from train.rl.config import TrainConfig

    with pytest.raises(TrainConfigError, match="unknown backend"):
        validate(TrainConfig(out=str(tmp_path / "x"), backend="jax"))
