"""``ptrack probe-actions``: how much of its authority a trained policy uses."""

from __future__ import annotations

import functools

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

from pathlib import Path

import numpy as np

from train.cli import run_command as _run_command
from train.studies.action_probe import ActionUsage, action_usage, main

train_main = functools.partial(_run_command, "train")


def test_statistics_of_a_known_action_array() -> None:
    a = np.array([[1.0, -0.5], [-0.95, 0.0], [0.1, 0.5], [-0.15, 0.0]])
    u = ActionUsage.of(a, threshold=0.9)
    assert u.steps == 4
    assert u.mean_abs == pytest.approx((1 + 0.5 + 0.95 + 0 + 0.1 + 0.5 + 0.15 + 0) / 8)
    assert u.saturated_fraction == pytest.approx(2 / 8)
    np.testing.assert_allclose(u.mean_per_joint, [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(
        u.std_per_joint, [np.std([1, -0.95, 0.1, -0.15]), np.std([-0.5, 0, 0.5, 0])]
    )


@pytest.mark.parametrize("bad", [np.zeros((0, 2)), np.zeros(3), np.zeros((2, 2, 2))])
def test_bad_action_arrays_are_refused(bad: np.ndarray) -> None:
    with pytest.raises(ValueError, match="steps, joints"):
        ActionUsage.of(bad)


def _train(out: Path, extra: list[str]) -> Path:
    train_main(
        [*extra, "--algo", "sac", "--steps", "200", "--out", str(out), "--seed", "0",
         "--episode-s", "0.2", "--eval-freq", "0", "--checkpoint-freq", "0",
         "--hp", "learning_starts=50", "--hp", "buffer_size=1000",
         "--hp", "policy_kwargs=dict(net_arch=[16])"]
    )  # fmt: skip
    return out


def test_a_frozen_zero_initialised_residual_uses_no_authority(tmp_path: Path, capsys) -> None:
    # the actor starts at exactly 0 and is frozen: the deterministic residual is 0 on
    # every step, the episode is its base's
    run = _train(
        tmp_path / "res",
        ["--residual", "passivity", "--zero-init-residual", "--freeze-actor"],
    )
    u = action_usage(run, seed=3)
    assert u.steps == 50  # 0.2 s at the two-link's 250 Hz training rate
    assert u.mean_abs == 0.0 and u.saturated_fraction == 0.0
    main([str(run), "--seed", "3"])
    assert "mean |a| 0.000" in capsys.readouterr().out


def test_a_trained_pure_policy_acts(tmp_path: Path) -> None:
    run = _train(tmp_path / "pure", ["--residual", "none"])
    u = action_usage(run, seed=3)
    assert u.mean_abs > 0.0 and u.mean_per_joint.shape == (2,)
    again = action_usage(run, seed=3)  # deterministic policy, seeded episode: same numbers
    assert again.mean_abs == u.mean_abs
    np.testing.assert_array_equal(again.std_per_joint, u.std_per_joint)
