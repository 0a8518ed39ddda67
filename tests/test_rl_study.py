"""``ptrack study``: learning curves from the checkpoints of a multi-seed
study (tiny runs: what they learned is irrelevant here, the plumbing is not)."""

from __future__ import annotations

import functools

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

import shutil
from pathlib import Path

import pandas as pd
import yaml

from ptrack_gym.errors import InvalidConfigError
from train.cli import run_command
from train.cli import run_command as _run_command
from train.rl.study import discover, sweep_config

train_main = functools.partial(_run_command, "train")


def _train(out: Path, residual: str, seed: int) -> None:
    zero_init = ["--zero-init-residual"] if residual != "none" else []
    train_main(
        [*zero_init, "--algo", "sac", "--residual", residual, "--steps", "200", "--out", str(out),
         "--seed", str(seed), "--disturbance", "periodic:1.0", "--episode-s", "0.2",
         "--eval-freq", "100", "--eval-episodes", "1", "--checkpoint-freq", "100",
         "--hp", "learning_starts=50", "--hp", "buffer_size=1000",
         "--hp", "policy_kwargs=dict(net_arch=[16])"]
    )  # fmt: skip


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("study")
    _train(root / "residual-passivity_s0", "passivity", 0)
    _train(root / "pure_s0", "none", 0)
    _train(root / "pure_s1", "none", 1)
    return root


def test_study_writes_curves_figure_and_final_table(study: Path, tmp_path: Path) -> None:
    assert (
        run_command(
            "study",
            [
                "--runs",
                str(study),
                "--out",
                str(tmp_path / "rep"),
                "--episodes",
                "2",
                "--workers",
                "1",
                "--no-progress",
                "--presets",  # those that act in 0.2-s episodes (no onset at 1-4 s)
                "none",
                "periodic",
                "noise",
            ],
        )
        == 0
    )
    out = tmp_path / "rep"
    curves = pd.read_csv(out / "learning_curves.csv")
    # every run × checkpoint (100, 200) × disturbance (none, periodic) has its mean
    assert len(curves) == 3 * 2 * 2
    assert set(curves["steps"]) == {100, 200}
    assert set(curves["group"]) == {"pure", "residual-passivity"}
    assert curves["path_dist_rms"].notna().all()
    episodes = pd.read_csv(out / "episodes.csv")
    # passivity, computed torque, PD + g alone + 6 checkpoints, 2 disturbances, 2 episodes
    assert len(episodes) == (3 + 6) * 2 * 2
    final = pd.read_csv(out / "final" / "episodes.csv")
    # the 3 controllers alone + 3 final checkpoints, 3 presets at level 1, 2 episodes
    assert len(final) == (3 + 3) * 3 * 2
    assert set(final["disturbance"]) == {"none", "periodic", "noise"}
    assert (out / "learning_curves.png").stat().st_size > 10_000
    table = (out / "final.md").read_text()
    assert "pure SAC @ 200 steps (vs pd_gravity)" in table
    assert "residual-passivity SAC @ 200 steps (vs passivity)" in table
    assert "passivity alone" in table and "computed_torque alone" in table
    assert "## Samples to reach the reference" in table and "| pure | pd_gravity" in table
    assert "IQM" in table and (out / "aggregate.png").exists()
    # the protocol: what each group trained on and what the study judges it on
    assert "## Protocol" in table
    protocol = table.split("## Final checkpoints")[0]
    rows = [ln for ln in protocol.splitlines() if ln.startswith("| pure |")]
    assert len(rows) == 1 and "the default path" in rows[0], protocol
    assert rows[0].startswith("| pure | 2 | sac | 200 | – |"), rows  # no tuned base
    assert "This study evaluates them on: path default, presets noise, none, periodic" in table
    # the curve value at the last checkpoint is the final table's per-seed figure
    last = curves[(curves["group"] == "residual-passivity") & (curves["steps"] == 200)]
    value = last[last["disturbance"] == "periodic"]["path_dist_rms"].item()
    assert f"{value:.2e}" in table


@pytest.mark.parametrize(
    ("key", "value"),
    [("disturbance", "push:1.0"), ("algo", "td3"), ("scale_fraction", 0.2), ("decision_every", 10)],
)
def test_runs_that_differ_in_what_they_share_are_refused(
    study: Path, tmp_path: Path, key: str, value: object
) -> None:
    """Study-wide keys differ between any two runs; group keys (the residual scale)
    between two runs of one group — here two pure runs, whose scale is otherwise moot."""
    root = tmp_path / "mixed"
    shutil.copytree(study / "pure_s0", root / "a")
    shutil.copytree(study / "pure_s1", root / "b")
    cfg_file = root / "b" / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    cfg["config"][key] = value
    cfg_file.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InvalidConfigError, match=key):
        discover(root)


@pytest.mark.parametrize("key", ["actor_bc_weight", "actor_lr_scale", "critic_warmup_steps"])
def test_a_run_written_before_a_key_existed_groups_with_its_default(
    study: Path, tmp_path: Path, key: str
) -> None:
    """A run whose config.yml lacks a group key (written by an older version) ran with the
    key's default: it groups with runs that write the default, and not with others."""
    root = tmp_path / "old"
    shutil.copytree(study / "pure_s0", root / "a")
    shutil.copytree(study / "pure_s1", root / "b")
    cfg_file = root / "a" / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    del cfg["config"][key]
    cfg_file.write_text(yaml.safe_dump(cfg))
    assert len(discover(root)) == 2
    other = root / "b" / "config.yml"
    cfg = yaml.safe_load(other.read_text())
    cfg["config"][key] = cfg["config"][key] / 2 if key == "actor_lr_scale" else 5
    other.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InvalidConfigError, match=key):
        discover(root)


def test_the_group_key_defaults_are_train_configs() -> None:
    from train.rl.config import TrainConfig
    from train.rl.study import GROUP_KEY_DEFAULTS, GROUP_KEYS, SHARED_KEY_DEFAULTS

    defaults = TrainConfig(out="")
    assert set(GROUP_KEY_DEFAULTS) == set(GROUP_KEYS)
    for key, value in {**GROUP_KEY_DEFAULTS, **SHARED_KEY_DEFAULTS}.items():
        assert getattr(defaults, key) == value, key


def test_a_folder_without_finished_runs_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidConfigError, match="no finished runs"):
        discover(tmp_path / "empty")


def test_a_normalized_run_without_its_statistics_is_refused(study: Path, tmp_path: Path) -> None:
    """Evaluating a VecNormalize run on raw observations would be silently wrong."""
    from train.evaluation.episode import EpisodeSettings, Task, run_episode

    run = tmp_path / "run"
    shutil.copytree(study / "residual-passivity_s0", run)
    (run / "vecnormalize.pkl").unlink()
    settings = EpisodeSettings(
        env_id="ptrack_gym/TwoLinkTrack-v0", episode_s=0.2, control_hz=250.0,
        start="on_path", failure_distance_rad=0.5, recovery_threshold_rad=0.01,
    )  # fmt: skip
    with pytest.raises(InvalidConfigError, match=r"vecnormalize\.pkl is missing"):
        run_episode(Task(f"sb3:{run}", "none", 0.0, 0, 0), settings)


def test_groups_on_different_bases_each_meet_their_own_base(study: Path, tmp_path: Path) -> None:
    """A residual over computed torque is its own group, compared with computed torque; a
    gated residual is a group of its own too; the sweeps hold every base alone."""
    root = tmp_path / "bases"
    shutil.copytree(study / "residual-passivity_s0", root / "a")
    for name, change in (("b", {"residual": "computed_torque"}), ("c", {"gate_rad": 0.01})):
        shutil.copytree(study / "residual-passivity_s0", root / name)
        cfg_file = root / name / "config.yml"
        cfg = yaml.safe_load(cfg_file.read_text())
        cfg["config"].update(change)
        cfg_file.write_text(yaml.safe_dump(cfg))
    shutil.copytree(study / "residual-passivity_s0", root / "d")
    (root / "d" / "deploy.yml").write_text("gate_rad: 0.002\n")  # gated at evaluation only
    runs = discover(root)
    assert sorted(r.group for r in runs) == [
        "residual-computed_torque", "residual-passivity", "residual-passivity-deploy-gated",
        "residual-passivity-gated",
    ]  # fmt: skip
    curves = sweep_config(runs, 2, tmp_path / "out", 1)
    final = sweep_config(runs, 2, tmp_path / "out" / "final", 1, ["none", "noise"])
    for cfg in (curves, final):
        assert cfg.controllers[:3] == ["computed_torque", "passivity", "pd_gravity"]
    assert len(curves.controllers) == 3 + 4 * 2  # every checkpoint (100, 200) of 4 runs
    assert final.controllers[3:] == [f"sb3:{r.path}@200" for r in runs]
    assert (final.disturbances, final.levels) == (["none", "noise"], [1.0])


def test_residuals_over_tuned_bases_are_compared_with_the_tuned_controllers(
    study: Path, tmp_path: Path
) -> None:
    """The controllers alone run with the gains the residuals' bases had (``base_gains``);
    a pure run does not count; residuals over differently tuned bases are refused."""
    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile

    profile = robot_profile("two_link")
    root = tmp_path / "tuned"
    shutil.copytree(study / "pure_s0", root / "pure_s0")
    for name in ("residual-passivity_s0", "residual-passivity_s1"):
        shutil.copytree(study / "residual-passivity_s0", root / name)
        cfg_file = root / name / "config.yml"
        cfg = yaml.safe_load(cfg_file.read_text())
        cfg["config"]["base_gains"] = "tuned"
        cfg["derived"]["base_rates"] = pinned_rates(profile, "passivity", "tuned")  # its pin
        cfg["config"]["seed"] = int(name[-1])
        cfg_file.write_text(yaml.safe_dump(cfg))
    runs = discover(root)
    curves = sweep_config(runs, 2, tmp_path / "out", 1)
    assert curves.gains == "tuned"
    assert sweep_config(discover(study), 2, tmp_path / "out", 1).gains == "default"
    # and each residual is evaluated over the tuned base it trained with
    from agents.registry import make_controller
    from train.evaluation.episode import _sb3_env_and_policy

    entry = next(c for c in curves.controllers if "residual-passivity_s1" in c)
    env, _ = _sb3_env_and_policy(entry, curves.settings(), "none", 0.0)  # the cache owns env
    tuned = make_controller("passivity", env, "tuned").gains
    assert env.get_wrapper_attr("controller").gains == tuned
    cfg_file = root / "residual-passivity_s1" / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    del cfg["config"]["base_gains"]  # a run written before the key: default gains
    cfg_file.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InvalidConfigError, match="gains differ"):
        discover(root)


def test_residuals_pinned_at_other_rates_are_compared_with_the_base_as_pinned(
    study: Path, tmp_path: Path
) -> None:
    """A residual whose base's rates have moved since it trained (a new default) is compared
    with its base at the rates it pinned: the base alone runs at them (``controller_rates``)
    and no mismatch is warned; residuals over one base that pinned different rates are
    refused; a study at today's rates sets none."""
    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile

    old = {**pinned_rates(robot_profile("two_link"), "passivity", "default"), "omega": 17.0}
    root = tmp_path / "moved"
    for name in ("residual-passivity_s0", "residual-passivity_s1"):
        shutil.copytree(study / "residual-passivity_s0", root / name)
        cfg_file = root / name / "config.yml"
        cfg = yaml.safe_load(cfg_file.read_text())
        cfg["derived"]["base_rates"] = old
        cfg["config"]["seed"] = int(name[-1])
        cfg_file.write_text(yaml.safe_dump(cfg))
    curves = sweep_config(discover(root), 2, tmp_path / "out", 1)
    assert curves.controller_rates == {"passivity": old}
    assert curves.settings().controller_gains("passivity", "two_link")["omega"] == 17.0
    assert curves.base_gain_mismatches() == []
    assert sweep_config(discover(study), 2, tmp_path / "out", 1).controller_rates == {}
    cfg_file = root / "residual-passivity_s1" / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    cfg["derived"]["base_rates"] = {**old, "omega": 18.0}
    cfg_file.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InvalidConfigError, match="pinned different base rates"):
        sweep_config(discover(root), 2, tmp_path / "out", 1)


def test_a_pure_run_that_imitated_a_controller_is_compared_with_that_expert(
    study: Path, tmp_path: Path
) -> None:
    """``imitate``: its reference is the expert (not PD + gravity) at the expert's gains;
    an expert's gains that differ from the residuals' bases' are refused."""
    from train.rl.study import reference_of

    root = tmp_path / "imitating"
    shutil.copytree(study / "pure_s0", root / "pure_s0")
    cfg_file = root / "pure_s0" / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    cfg["config"].update(imitate="computed_torque", imitate_gains="tuned")
    cfg_file.write_text(yaml.safe_dump(cfg))
    runs = discover(root)
    assert reference_of(runs[0]) == "computed_torque"
    sweep = sweep_config(runs, 2, tmp_path / "out", 1)
    assert sweep.gains == "tuned"
    assert sweep.controllers[:2] == ["computed_torque", "pd_gravity"]
    assert reference_of(next(r for r in discover(study) if r.base == "none")) == "pd_gravity"
    shutil.copytree(study / "residual-passivity_s0", root / "residual-passivity_s0")  # default
    with pytest.raises(InvalidConfigError, match="gains differ"):
        discover(root)


def test_a_residual_over_a_network_is_compared_with_that_network(
    study: Path, tmp_path: Path
) -> None:
    """A network base's reference is its model (``sb3:<base_model>``, a reference alone, not
    a checkpoint of the study) at the gains of the controller it imitated."""
    from train.rl.study import is_checkpoint_entry, reference_of

    base = tmp_path / "imitation"
    shutil.copytree(study / "pure_s0", base)
    base_cfg = yaml.safe_load((base / "config.yml").read_text())
    base_cfg["config"].update(imitate="pd_gravity", imitate_gains="tuned")
    (base / "config.yml").write_text(yaml.safe_dump(base_cfg))
    root = tmp_path / "over-network"
    shutil.copytree(study / "residual-passivity_s0", root / "residual-network_s0")
    cfg_file = root / "residual-network_s0" / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    cfg["config"].update(residual="network", base_model=str(base))
    cfg_file.write_text(yaml.safe_dump(cfg))
    runs = discover(root)
    assert reference_of(runs[0]) == f"sb3:{base}"
    sweep = sweep_config(runs, 2, tmp_path / "out", 1)
    assert sweep.reference == f"sb3:{base}" and sweep.gains == "tuned"
    assert not is_checkpoint_entry(sweep.reference)
    mine = [c for c in sweep.controllers if c.startswith(f"sb3:{runs[0].path}")]
    assert mine and all(is_checkpoint_entry(c) for c in mine)


def test_thinning_keeps_multiples_and_the_last_checkpoint(study: Path) -> None:
    from train.rl.study import thin

    runs = discover(study)
    assert [r.checkpoints for r in thin(runs, 200)] == [(200,)] * 3
    assert [r.checkpoints for r in thin(runs, 100)] == [(100, 200)] * 3
    with pytest.raises(InvalidConfigError):
        thin(runs, 0)


def test_campaign_folder_names_are_the_groups(study: Path, tmp_path: Path) -> None:
    """``<group>_s<seed>`` folders (train.rl.campaign's) keep the campaign's group names,
    so two groups on one base with different safeguards stay apart."""
    root = tmp_path / "named"
    for name, penalty in (("res-a_s0", 0.0), ("res-b_s0", 0.2)):
        shutil.copytree(study / "residual-passivity_s0", root / name)
        cfg_file = root / name / "config.yml"
        cfg = yaml.safe_load(cfg_file.read_text())
        cfg["config"]["action_penalty"] = penalty
        cfg_file.write_text(yaml.safe_dump(cfg))
    runs = discover(root)
    assert sorted(r.group for r in runs) == ["res-a", "res-b"]
    assert {r.base for r in runs} == {"passivity"}


@pytest.mark.parametrize("where", ["config", "deploy"])
def test_a_deadband_run_is_evaluated_with_its_deadband(
    study: Path, tmp_path: Path, where: str
) -> None:
    """The evaluation env is built with the run's gate and deadband — from its training
    config, or from a deploy.yml put beside a run trained without one: undisturbed, the
    deadband-gated residual's episode has exactly its base's metrics."""
    from train.evaluation.episode import EpisodeSettings, Task, run_episode

    run = tmp_path / "deadband"
    shutil.copytree(study / "residual-passivity_s0", run)
    gate = {"gate_rad": 0.002, "gate_deadband_rad": 0.002}
    if where == "config":
        cfg_file = run / "config.yml"
        cfg = yaml.safe_load(cfg_file.read_text())
        cfg["config"].update(gate)
        cfg_file.write_text(yaml.safe_dump(cfg))
    else:
        (run / "deploy.yml").write_text(yaml.safe_dump(gate))
    settings = EpisodeSettings(
        env_id="ptrack_gym/TwoLinkTrack-v0", episode_s=2.0, control_hz=250.0,
        start="on_path", failure_distance_rad=0.5, recovery_threshold_rad=0.01,
    )  # fmt: skip
    plain = f"sb3:{study / 'residual-passivity_s0'}"
    for seed in (0, 3):
        learned, _ = run_episode(Task(f"sb3:{run}", "none", 0.0, seed, 0), settings)
        base, _ = run_episode(Task("passivity", "none", 0.0, seed, 0), settings)
        for key in ("path_dist_rms", "path_dist_max", "time_err_rms", "tau_dyn_rms_frac"):
            assert learned[key] == base[key]
        ungated, _ = run_episode(Task(plain, "none", 0.0, seed, 0), settings)
        assert ungated["path_dist_rms"] != base["path_dist_rms"]  # the run's policy does act


def test_a_run_is_evaluated_with_its_acceleration_authority(study: Path, tmp_path: Path) -> None:
    """The evaluation env takes the run's scale_accel_rad_s2: at α = 0 the residual has no
    authority, so the run's episode is its base's, metric for metric (the run itself acts)."""
    from train.evaluation.episode import EpisodeSettings, Task, run_episode

    run = tmp_path / "accel0"
    shutil.copytree(study / "residual-passivity_s0", run)
    cfg_file = run / "config.yml"
    cfg = yaml.safe_load(cfg_file.read_text())
    cfg["config"]["scale_accel_rad_s2"] = 0.0
    cfg_file.write_text(yaml.safe_dump(cfg))
    settings = EpisodeSettings(
        env_id="ptrack_gym/TwoLinkTrack-v0", episode_s=1.0, control_hz=250.0,
        start="on_path", failure_distance_rad=0.5, recovery_threshold_rad=0.01,
    )  # fmt: skip
    learned, _ = run_episode(Task(f"sb3:{run}", "periodic", 1.0, 1, 0), settings)
    base, _ = run_episode(Task("passivity", "periodic", 1.0, 1, 0), settings)
    for key in ("path_dist_rms", "path_dist_max", "time_err_rms", "tau_dyn_rms_frac"):
        assert learned[key] == base[key]
    plain = f"sb3:{study / 'residual-passivity_s0'}"
    acting, _ = run_episode(Task(plain, "periodic", 1.0, 1, 0), settings)
    assert acting["path_dist_rms"] != base["path_dist_rms"]


@pytest.mark.parametrize(
    ("run", "text", "match"),
    [
        ("residual-passivity_s0", "gate_rad: 0.01\nscale_fraction: 0.5\n", "expected a mapping"),
        ("residual-passivity_s0", "- gate_rad\n", "expected a mapping"),
        ("residual-passivity_s0", "gate_rad: -0.01\n", "gate_rad must be"),
        ("residual-passivity_s0", "gate_deadband_rad: 0.01\n", "needs gate_rad"),
        ("pure_s0", "gate_rad: 0.01\n", "need a residual run"),
        ("residual-passivity_s0", "tank: 1\n", "tank must be true or false"),
    ],
)
def test_a_bad_deploy_file_is_named_before_anything_runs(
    study: Path, tmp_path: Path, run: str, text: str, match: str
) -> None:
    from train.evaluation.policies import check_sb3_run, deploy_safeguards

    folder = tmp_path / run
    shutil.copytree(study / run, folder)
    assert deploy_safeguards(folder) == {}
    (folder / "deploy.yml").write_text(text)
    with pytest.raises(InvalidConfigError, match=match):
        check_sb3_run(f"sb3:{folder}", "ptrack_gym/TwoLinkTrack-v0")


def test_samples_to_reach_says_an_imitating_runs_steps_are_rl_steps_only(
    study: Path, tmp_path: Path
) -> None:
    import json

    from train.rl.study import samples_to_reach

    root = tmp_path / "imitating"
    shutil.copytree(study / "pure_s0", root / "pure_s0")
    runs = discover(root)
    curves = pd.DataFrame(
        {"group": ["pure"] * 2, "seed": [0, 0], "steps": [100, 200],
         "disturbance": ["impulse"] * 2, "path_dist_rms": [0.5, 0.001]}
    )  # fmt: skip
    baselines = {"impulse": {"pd_gravity": 0.01}}
    plain = samples_to_reach(curves, baselines, runs, "impulse")
    assert "| 200 |" in plain and "imitation" not in plain
    (root / "pure_s0" / "imitation.json").write_text(json.dumps({"env_steps": 1234}))
    noted = samples_to_reach(curves, baselines, runs, "impulse")
    assert "pure also took 1234 env steps" in noted


def test_samples_to_reach_counts_only_checkpoints_whose_actor_trained(
    study: Path, tmp_path: Path
) -> None:
    """A zero-initialised residual is its base until its actor's first update (past
    learning_starts + critic_warmup_steps): its checkpoints before it "reach" the base at
    once and must not count; a run with none after it was never trained."""
    from train.rl.study import samples_to_reach

    root = tmp_path / "warm"
    for name, warmup in (("res-a_s0", 500), ("res-b_s0", 100)):
        shutil.copytree(study / "residual-passivity_s0", root / name)
        cfg_file = root / name / "config.yml"
        cfg = yaml.safe_load(cfg_file.read_text())
        cfg["config"]["critic_warmup_steps"] = warmup
        cfg_file.write_text(yaml.safe_dump(cfg))
    runs = discover(root)
    assert [(r.group, r.untrained_through) for r in runs] == [("res-a", 550), ("res-b", 150)]
    curves = pd.DataFrame(
        {"group": ["res-a", "res-a", "res-b", "res-b"], "seed": [0] * 4,
         "steps": [100, 200, 100, 200], "disturbance": ["impulse"] * 4,
         "path_dist_rms": [0.01, 0.01, 0.01, 0.009]}
    )  # fmt: skip
    table = samples_to_reach(curves, {"impulse": {"passivity": 0.01}}, runs, "impulse")
    assert "| res-a | passivity (1.00e-02 rad) | never trained | 0/1 | — |" in table
    assert "| res-b | passivity (1.00e-02 rad) | 200 | 1/1 | 200 |" in table
    assert "Never trained:" in table
    frozen = root / "res-b_s0" / "config.yml"
    cfg = yaml.safe_load(frozen.read_text())
    cfg["config"]["freeze_actor"] = True
    frozen.write_text(yaml.safe_dump(cfg))
    assert discover(root)[1].untrained_through == float("inf")


def test_a_study_needs_two_episodes_per_policy(tmp_path: Path) -> None:
    """One episode has no bootstrap interval (the table would print [+nan, +nan])."""
    from train.rl.study import StudyConfig

    with pytest.raises(InvalidConfigError, match="episodes must be >= 2, got 1"):
        StudyConfig(runs=str(tmp_path), out=str(tmp_path / "o"), episodes=1).validate()
    with pytest.raises(SystemExit) as exc:
        run_command("study", ["--runs", str(tmp_path), "--out", str(tmp_path / "o"),
                              "--episodes", "1"])  # fmt: skip
    assert exc.value.code == 2
    assert not (tmp_path / "o").exists()


def test_the_curves_of_family_trained_runs_run_under_their_families() -> None:
    from train.rl.study_runs import training_conditions

    assert training_conditions({"disturbance": "impulse:1.0"}) == [("impulse", 1.0)]
    assert training_conditions({"disturbance": "none"}) == []
    families = {"disturbance": "none", "train_families": ["impulse:1.0", "payload", "noise:1"]}
    assert training_conditions(families) == [("impulse", 1.0), ("payload", 1.0), ("noise", 1.0)]


def test_the_tuning_budget_of_a_base_is_read_from_its_tuned_file(tmp_path, monkeypatch) -> None:
    import agents.registry as registry
    from train.evaluation.protocol import tuning_env_steps

    monkeypatch.setattr(registry, "TUNED_DIR", tmp_path)
    (tmp_path / "two_link-passivity.yml").write_text("rates: {}\nstudy: {env_steps: 1234}\n")
    (tmp_path / "two_link-pd_gravity.yml").write_text("rates: {}\nstudy: {seed: 0}\n")
    assert tuning_env_steps("two_link", "passivity") == 1234
    assert tuning_env_steps("two_link", "pd_gravity") is None  # an older protocol's file
    assert tuning_env_steps("two_link", "slotine_li") is None  # no file
