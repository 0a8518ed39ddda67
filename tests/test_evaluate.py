"""The evaluation harness: a tiny sweep end to end, resume, workers, Ray, pairing, and
the refusal of corrupt results files and bad configs."""

from __future__ import annotations

import dataclasses
import functools
import os
import shutil
import sys
import threading
import types

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import ptrack_gym  # noqa: F401
from agents.policy import ControllerPolicy
from agents.registry import make_controller
from ptrack_gym.errors import InvalidConfigError
from train.cli import run_command
from train.common import runs
from train.evaluation import sweep
from train.evaluation.config import load_config
from train.evaluation.episode import Task, run_episode
from train.evaluation.results import COLUMNS, CorruptResultsError, read_episodes
from train.evaluation.sweep import _run_processes, finish, run_sweep

TINY = [
    "env_id=ptrack_gym/TwoLinkTrack-v0",
    "controllers=[computed_torque, passivity]",
    "disturbances=[none, periodic]",  # acts from t = 0: an impulse (1-4 s) needs >= 4.55 s
    "levels=[1.0]",
    "seeds=2",
    "episode_s=0.4",
    "bootstrap_resamples=200",
    "reference=computed_torque",
]


def main(argv: list[str]) -> int:
    """``ptrack evaluate`` with ``argv``."""
    return run_command("evaluate", argv)


def tiny(tmp_path, name, *extra):
    return load_config(None, [*TINY, f"out={tmp_path / name}", *extra])


def numbers(path):
    df = pd.read_csv(path).drop(columns=["wall_s"])
    return df.sort_values(["controller", "disturbance", "level", "seed", "episode"]).reset_index(
        drop=True
    )


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("eval")
    return run_sweep(tiny(tmp, "full", "workers=1"), progress=False)


def test_tiny_sweep_writes_tables_provenance_and_plots(full_run) -> None:
    out = full_run
    df = pd.read_csv(out / "episodes.csv")
    assert list(df.columns) == list(COLUMNS)
    # 2 controllers × (none + periodic@1) × 2 seeds × 1 episode
    assert len(df) == 8
    assert set(df["controller"]) == {"computed_torque", "passivity"}
    assert df["path_dist_rms"].notna().all() and (df["steps"] == 400).all()
    summary = pd.read_csv(out / "summary.csv")
    assert len(summary) == 4
    assert {"path_dist_rms_mean", "mean_ci_low", "failure_rate", "diff_vs_computed_torque"} <= set(
        summary.columns
    )
    ref = summary[summary["controller"] == "computed_torque"]
    assert (ref["diff_vs_computed_torque"] == 0.0).all()
    for name in (
        "config.yml",
        "command.txt",
        "summary.md",
        "robustness_path_dist_rms.png",
        "failures.png",
        "example_passivity.png",
        "example_computed_torque.png",
        "aggregate.png",
    ):
        assert (out / name).stat().st_size > 0, name
    assert not (out / "videos").exists()  # video is opt-in


def test_a_sweep_of_one_controller_reports_it_without_comparisons(tmp_path) -> None:
    """One controller is its own reference: tables and report are written, the
    comparisons file has its columns and no rows."""
    cfg = tiny(tmp_path, "one", "controllers=[passivity]", "reference=passivity", "workers=1")
    out = run_sweep(cfg, progress=False)
    assert set(pd.read_csv(out / "episodes.csv")["controller"]) == {"passivity"}
    comparisons = pd.read_csv(out / "comparisons.csv")
    assert comparisons.empty and "mark" in comparisons.columns
    report = (out / "report.md").read_text()
    assert "Only passivity was evaluated: there is nothing to compare." in report
    assert "| passivity |" in report


def test_video_records_the_example_episode_of_every_controller(tmp_path) -> None:
    pytest.importorskip("moviepy", reason="the optional 'video' extra (MoviePy) is not installed")
    out = run_sweep(
        tiny(tmp_path, "video", "workers=1", "seeds=1", "plots=false", "video=true"),
        progress=False,
    )
    for ctrl in ("passivity", "computed_torque"):
        assert (out / "videos" / ctrl / f"{ctrl}-episode-0.mp4").stat().st_size > 1000
    assert not list(out.glob("*.png"))  # plots=false: no figure, the aggregate's included


def test_the_video_runs_the_sweeps_gains_and_path(tmp_path, monkeypatch) -> None:
    """The example episode filmed is the sweep's: its controller's own rates and its path
    (it ran every controller at default gains on the default path)."""
    pytest.importorskip("moviepy", reason="the optional 'video' extra (MoviePy) is not installed")
    import train.evaluation.video as video

    calls = {}
    monkeypatch.setattr(
        video, "record_episode", lambda env_id, ctrl, *a, **kw: calls.setdefault(ctrl, kw)
    )
    cfg = tiny(
        tmp_path, "film", "seeds=1", "plots=false", "video=true", "path=random", "path_seed=3",
        "controller_rates={passivity: {damping_ratio: 0.25}}",
    )  # fmt: skip
    run_sweep(cfg, progress=False)
    assert calls["passivity"]["gains"] == {"damping_ratio": 0.25}
    assert calls["computed_torque"]["gains"] == "default"
    for kw in calls.values():
        assert kw["env_kwargs"]["path"] == "random" and kw["env_kwargs"]["path_seed"] == 3


@pytest.mark.parametrize(
    ("module", "override"), [("moviepy", "video=true"), ("ray", "backend=ray")]
)
def test_an_option_whose_extra_is_missing_is_refused_before_running(
    tmp_path, monkeypatch, module, override
) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == module else real(name, *a)
    )
    with pytest.raises(
        InvalidConfigError, match=f"'{'video' if module == 'moviepy' else 'ray'}' extra"
    ):
        tiny(tmp_path, "x", override)
    assert not (tmp_path / "x").exists()


def test_resume_completes_without_duplicates(full_run, tmp_path) -> None:
    out = tmp_path / "resumed"
    shutil.copytree(full_run, out)
    lines = (out / "episodes.csv").read_text().splitlines(keepends=True)
    (out / "episodes.csv").write_text("".join(lines[:4]))  # header + 3 episodes: "interrupted"
    with pytest.raises(InvalidConfigError, match="--resume"):
        run_sweep(tiny(tmp_path, "resumed", "workers=1"), progress=False)
    run_sweep(tiny(tmp_path, "resumed", "workers=1"), resume=True, progress=False)
    rows = read_episodes(out / "episodes.csv")
    assert len(rows) == 8
    pd.testing.assert_frame_equal(numbers(out / "episodes.csv"), numbers(full_run / "episodes.csv"))


def test_a_resume_at_changed_gains_is_refused_or_reruns_exactly_those_rows(
    full_run, tmp_path
) -> None:
    """The sweep records each controller's rates; a resume at other gains for one of them
    is refused naming it, and ``rerun_changed`` runs exactly its rows again."""
    import yaml

    from train.evaluation.rate_record import RATES_KEY

    out = tmp_path / "retuned"
    shutil.copytree(full_run, out)
    saved = yaml.safe_load((out / "config.yml").read_text())
    table = saved[RATES_KEY]["two_link"]
    assert set(table) == {"computed_torque", "passivity"}
    victim = "computed_torque"
    table[victim] = {**table[victim], "omega": 2.0 * table[victim]["omega"]}  # ran at others
    (out / "config.yml").write_text(yaml.safe_dump(saved, sort_keys=False))
    before = (out / "episodes.csv").read_text()
    with pytest.raises(InvalidConfigError, match=f"gains of {victim} on two_link changed"):
        run_sweep(tiny(tmp_path, "retuned", "workers=1"), resume=True, progress=False)
    assert (out / "episodes.csv").read_text() == before  # nothing lost
    # another setting changed as well: refused on that setting before any row is dropped
    with pytest.raises(InvalidConfigError, match="different settings: seeds 2 -> 3"):
        run_sweep(tiny(tmp_path, "retuned", "workers=1", "seeds=3"), resume=True,
                  progress=False, rerun_changed=True)  # fmt: skip
    assert (out / "episodes.csv").read_text() == before
    with pytest.raises(InvalidConfigError, match="--rerun-changed acts on a resume"):
        run_sweep(tiny(tmp_path, "retuned", "workers=1"), progress=False, rerun_changed=True)
    run_sweep(
        tiny(tmp_path, "retuned", "workers=1"), resume=True, progress=False, rerun_changed=True
    )
    rows = read_episodes(out / "episodes.csv")
    assert len(rows) == 8 and [r["controller"] for r in rows[-4:]] == [victim] * 4
    pd.testing.assert_frame_equal(numbers(out / "episodes.csv"), numbers(full_run / "episodes.csv"))
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved[RATES_KEY] == yaml.safe_load((full_run / "config.yml").read_text())[RATES_KEY]


# An earlier test may leave an idle thread in this process (tqdm's monitor, after a CLI run
# with a progress bar); these tests force a fork all the same, which Python >= 3.12 warns
# about. "auto" would spawn here (tested below).
FORK_WARNING = "ignore:This process .* is multi-threaded:DeprecationWarning"


@pytest.mark.filterwarnings(FORK_WARNING)
@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_two_workers_give_the_same_numbers_and_figures(full_run, tmp_path, method) -> None:
    """workers=2 (the plots drawn by the worker process while this process writes the
    report), forked or spawned: the same rows, summary and report, and byte-identical
    figures."""
    out = run_sweep(tiny(tmp_path, "two", "workers=2", f"start_method={method}"), progress=False)
    pd.testing.assert_frame_equal(numbers(out / "episodes.csv"), numbers(full_run / "episodes.csv"))
    figures = sorted(p.name for p in full_run.glob("*.png"))
    assert {"robustness_path_dist_rms.png", "example_passivity.png", "aggregate.png"} <= set(
        figures
    )
    assert sorted(p.name for p in out.glob("*.png")) == figures
    for name in [*figures, "summary.csv", "report.md"]:
        assert (out / name).read_bytes() == (full_run / name).read_bytes(), name


def _episode_and_pid(task, settings, keep_trace):
    """run_episode, its row tagged with the id of the process that ran it."""
    row, trace = run_episode(task, settings, keep_trace)
    return {**row, "pid": os.getpid()}, trace


def test_two_runners_share_the_tasks_and_a_failed_episode_stops_the_sweep(
    tmp_path, monkeypatch
) -> None:
    """workers=2: this process and one spawned worker take tasks from one queue — both run
    episodes —; every task comes back once, and an episode that raises (here an unknown
    controller, wherever it ran) ends the sweep with its error instead of being skipped."""
    cfg = tiny(tmp_path, "runners", "workers=2")
    tasks, settings = cfg.tasks(), cfg.settings()
    monkeypatch.setattr(sweep, "run_episode", _episode_and_pid)
    results = list(_run_processes(tasks, settings, 2, set()))
    assert sorted(task.key() for _, _, task in results) == sorted(t.key() for t in tasks)
    pids = {row["pid"] for row, _, _ in results}
    assert os.getpid() in pids and len(pids) == 2
    bad = dataclasses.replace(tasks[1], controller="no_such_controller")
    with pytest.raises(InvalidConfigError, match="no_such_controller"):
        list(_run_processes([tasks[0], bad, *tasks[2:]], settings, 2, set()))


def test_auto_start_method_forks_only_where_a_fork_is_safe(monkeypatch) -> None:
    """ "auto" forks on Linux (Python >= 3.11) in a single-threaded process without torch or
    JAX; a second thread, an imported torch/JAX, Python 3.10 or another platform make it
    spawn; an explicit method is kept."""
    for name in runs.FORK_UNSAFE_MODULES:
        monkeypatch.delitem(sys.modules, name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    real_thread_count = runs._thread_count
    # Earlier tests may leave a thread behind (tqdm's monitor): count this one alone.
    monkeypatch.setattr(runs, "_thread_count", lambda: 1)
    assert runs.start_method("auto") == "fork"
    assert runs.start_method("spawn") == "spawn"
    for name in ("torch", "jax"):
        with monkeypatch.context() as m:
            m.setitem(sys.modules, name, types.ModuleType(name))
            assert runs.start_method("auto") == "spawn"
            assert runs.start_method("fork") == "fork"
    with monkeypatch.context() as m:
        m.setattr(sys, "platform", "darwin")
        assert runs.start_method("auto") == "spawn"
    with monkeypatch.context() as m:  # 3.10's fork pools may fork after their own thread
        m.setattr(sys, "version_info", (3, 10, 13, "final", 0))
        assert runs.start_method("auto") == "spawn"
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    monkeypatch.setattr(runs, "_thread_count", real_thread_count)
    try:
        assert runs._thread_count() >= 2
        assert runs.start_method("auto") == "spawn"
    finally:
        release.set()
        other.join()


@pytest.mark.filterwarnings(FORK_WARNING)
def test_forked_workers_start_with_the_pool_before_any_other_thread() -> None:
    """A fork pool forks its workers when it is made (its first submit), so a thread this
    process starts afterwards (the local runner, tqdm's monitor) is never copied into a
    half-held state; a spawn pool starts its workers on the first task."""
    forked = runs.worker_pool(2, "fork")
    try:
        assert len(forked._processes) == 2
        assert set(forked.map(_pid, range(8))) <= set(forked._processes)
    finally:
        forked.shutdown()
    spawned = runs.worker_pool(1, "spawn")
    try:
        assert len(spawned._processes) == 0
    finally:
        spawned.shutdown()


def _pid(_: int) -> int:
    return os.getpid()


def test_summary_and_report_do_not_depend_on_the_order_episodes_finished(
    full_run, tmp_path
) -> None:
    """episodes.csv holds rows in the order they finished, which parallel runners change
    from run to run: the bootstrap intervals of the summary and the report must not. Six
    seeds (the tiny sweep's rows copied with other seeds and metric values), written once
    sorted and once shuffled, give byte-identical summaries and reports."""
    rng = np.random.default_rng(0)
    base = pd.read_csv(full_run / "episodes.csv")
    copies = []
    for k in range(3):
        c = base.copy()
        c["seed"] += 2 * k
        c["path_dist_rms"] *= rng.uniform(0.5, 2.0, len(c))
        copies.append(c)
    rows = pd.concat(copies, ignore_index=True).sort_values(
        ["controller", "disturbance", "level", "seed", "episode"]
    )
    outputs = {}
    for name, frame in (("sorted", rows), ("shuffled", rows.sample(frac=1.0, random_state=1))):
        folder = tmp_path / name
        folder.mkdir()
        frame.to_csv(folder / "episodes.csv", index=False, float_format="%.17g", na_rep="nan")
        finish(tiny(tmp_path, name, "seeds=6", "plots=false"), folder, show=False)
        outputs[name] = {f: (folder / f).read_bytes() for f in ("summary.csv", "report.md")}
        assert not list(folder.glob("*.png"))  # plots=false: no figure, nor the aggregate's
        assert b"## Aggregate over conditions" in outputs[name]["report.md"]
    assert outputs["sorted"] == outputs["shuffled"]


@pytest.mark.slow  # Ray's start takes most of a minute: make test-slow
def test_ray_backend_gives_the_same_rows(full_run, tmp_path) -> None:
    pytest.importorskip("ray")
    out = run_sweep(
        tiny(tmp_path, "ray", "workers=2", "backend=ray", "plots=false"), progress=False
    )
    pd.testing.assert_frame_equal(numbers(out / "episodes.csv"), numbers(full_run / "episodes.csv"))


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda text: text[:-5], "incomplete"),
        (lambda text: text.replace("controller,", "ctrl,", 1), "header"),
        (lambda text: text + text.splitlines(keepends=True)[1], "twice"),
        (lambda text: text + "a,b,c\n", "fields"),
    ],
    ids=["partial-line", "foreign-header", "duplicate", "short-row"],
)
def test_corrupt_results_are_refused(full_run, tmp_path, mutate, match) -> None:
    out = tmp_path / "bad"
    shutil.copytree(full_run, out)
    path = out / "episodes.csv"
    path.write_text(mutate(path.read_text()))
    with pytest.raises(CorruptResultsError, match=match):
        run_sweep(tiny(tmp_path, "bad", "workers=1"), resume=True, progress=False)


@pytest.mark.parametrize(
    "override",
    [
        "controllers=[pd_gravity, pd_gravity]",
        "levels=[0.5, 0.5]",
        "metric=path_rms",
        "start=flying",
        "control_hz=300",
        "controllers=[magic]",
        "disturbances=[hurricane]",
        "levels=[-1]",
        "bogus=1",
        "backend=spark",
        "start_method=teleport",
        "reference=magic",
        "seeds=0",
        "path=spiral",
        "path_seed=1.5",
        "worst_case=null",
        "worst_case=docs/results/adversary_iiwa",
        "controller_rates={magic: {omega: 1.0}}",
        "controller_rates={passivity: {warp: 1.0}}",
        "controller_rates={passivity: {omega: .nan}}",
        "controller_rates={passivity: {}}",
        "controller_rates=[1]",
        "controller_rates={passivity: {damping_ratio: -0.5}}",
        "controller_rates={passivity: {omega: 1e400}}",
        "controller_rates={passivity_paper: {damping_ratio: 0.5}}",  # its law fixes 0
    ],
)
def test_bad_config_is_refused_before_running(tmp_path, override, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "--config",
                "train/configs/evaluate/main.yml",
                "--set",
                override,
                "--out",
                str(tmp_path / "x"),
            ]
        )
    assert exc.value.code == 2
    assert not (tmp_path / "x" / "episodes.csv").exists()


def test_a_sweep_on_another_path_runs_every_entrant_on_that_path(monkeypatch) -> None:
    """``path``/``path_seed`` reach the env of a model-based controller and of a trained
    model alike (a held-out path for the RL entrants): the episode is the one a direct
    ``gym.make(path=..., path_seed=...)`` rollout gives."""
    from pathlib import Path

    pytest.importorskip("stable_baselines3", reason="the optional 'train' extra is not installed")
    from train.evaluation.episode import _sb3_env_and_policy

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    cfg = load_config(
        Path("train/configs/evaluate/main_rl.yml"),
        ["episode_s=0.4", "path=random", "path_seed=3", "disturbances=[none]"],  # 0.4 s: no onset
    )
    settings = cfg.settings()
    default = dataclasses.replace(settings, path="default", path_seed=None)
    env, _ = _sb3_env_and_policy("sb3:models/sac_residual_passivity_twolink", settings, "none", 0)
    reference = gym.make(
        "ptrack_gym/TwoLinkTrack-v0", control_hz=250.0, path="random", path_seed=3
    ).unwrapped.path
    for s in (0.0, 0.7, 1.9):
        np.testing.assert_array_equal(env.unwrapped.path.evaluate(s)[0], reference.evaluate(s)[0])
    task = Task("pd_gravity", "none", 0.0, 0, 0)
    row, _ = run_episode(task, settings)
    row_default, _ = run_episode(task, default)
    assert row["path_dist_rms"] != row_default["path_dist_rms"]
    direct = gym.make(
        "ptrack_gym/TwoLinkTrack-v0", control_hz=250.0, path="random", path_seed=3,
        max_episode_steps=100, horizon_s=0.4,
    )  # fmt: skip
    policy = ControllerPolicy(direct, make_controller("pd_gravity", direct))
    obs, _ = direct.reset(seed=task.reset_seed)
    dist = []
    for _ in range(100):
        obs, _, _, _, info = direct.step(policy.predict(obs)[0])
        dist.append(info["path_distance"])
    assert row["path_dist_rms"] == pytest.approx(
        float(np.sqrt(np.mean(np.square(dist)))), rel=1e-12
    )


def test_paired_controllers_meet_identical_disturbances() -> None:
    """Same seed → the recorded disturbance torques are identical for two controllers."""
    series = {}
    for name in ("computed_torque", "pd_gravity"):
        env = gym.make(
            "ptrack_gym/TwoLinkTrack-v0",
            disturbance=["impulse", "periodic"],
            max_episode_steps=2500,
        )
        policy = ControllerPolicy(env, make_controller(name, env))
        obs, _ = env.reset(seed=7)
        taus = []
        for _ in range(2500):
            obs, _, _terminated, _truncated, info = env.step(policy.predict(obs)[0])
            taus.append(info["disturbance_torque_nm"])
        series[name] = (np.array(taus), env.unwrapped.disturbance_schedule())
        env.close()
    (a, sched_a), (b, sched_b) = series.values()
    np.testing.assert_array_equal(a, b)
    assert np.abs(a).max() > 0
    assert str(sched_a) == str(sched_b)


def test_a_trained_residual_model_is_evaluated_like_a_controller(tmp_path) -> None:
    """``sb3:<run folder>`` runs a model of ``train.rl.run`` in the sweep (a 200-step SAC
    residual on passivity: what it learned is irrelevant here, the plumbing is not)."""
    pytest.importorskip(
        "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
    )
    from train.cli import run_command as _run_command

    train_main = functools.partial(_run_command, "train")

    run_dir = tmp_path / "sac_res"
    train_main(
        ["--algo", "sac", "--residual", "passivity", "--steps", "200", "--out", str(run_dir),
         "--episode-s", "0.2", "--eval-freq", "0", "--checkpoint-freq", "100",
         "--hp", "learning_starts=50", "--hp", "buffer_size=1000",
         "--hp", "policy_kwargs=dict(net_arch=[16])"]
    )  # fmt: skip
    final, early, latest = f"sb3:{run_dir}", f"sb3:{run_dir}@100", f"sb3:{run_dir}@200"
    controllers = f"controllers=[computed_torque, {final}, {early}, {latest}]"
    cfg = tiny(tmp_path, "with_model", "workers=1", controllers)
    out = run_sweep(cfg, progress=False)
    df = pd.read_csv(out / "episodes.csv")
    rows = {c: df[df["controller"] == c].reset_index(drop=True) for c in (final, early, latest)}
    for model_rows in rows.values():
        assert len(model_rows) == 4
        assert np.isfinite(model_rows["path_dist_rms"]).all()
        # At its training rate of 250 Hz, 0.4 s is 100 steps.
        assert (model_rows["steps"] == 100).all()
    # The 200-step checkpoint is the final model: the same episodes, bit for bit; the
    # 100-step one is another policy.
    assert rows[latest]["path_dist_rms"].tolist() == rows[final]["path_dist_rms"].tolist()
    assert rows[early]["path_dist_rms"].tolist() != rows[final]["path_dist_rms"].tolist()
    assert (out / "example_sb3-sac_res.png").exists()
    assert (out / "example_sb3-sac_res-100.png").exists()
    report = (out / "report.md").read_text()  # the protocol of every learned entrant
    assert "## What the learned entrants trained on" in report
    assert f"| {early} | two_link | sac | 100 | – | the default path | none | ±0 | – |" in report
    assert f"| {final} | two_link | sac | 200 |" in report
    with pytest.raises(InvalidConfigError, match="does not exist"):
        tiny(tmp_path, "x", f"controllers=[computed_torque, sb3:{tmp_path / 'nope'}]")
    with pytest.raises(InvalidConfigError, match="does not exist"):
        tiny(tmp_path, "x", f"controllers=[computed_torque, sb3:{run_dir}@150]")
    with pytest.raises(InvalidConfigError, match="step count"):
        tiny(tmp_path, "x", f"controllers=[computed_torque, sb3:{run_dir}@last]")


def test_resume_refuses_a_different_sweep(full_run, tmp_path) -> None:
    out = tmp_path / "other"
    shutil.copytree(full_run, out)
    longer = tiny(tmp_path, "other", "workers=1", "episode_s=0.2")
    with pytest.raises(InvalidConfigError, match="episode_s"):
        run_sweep(longer, resume=True, progress=False)
    # Fields that change no episode may differ.
    run_sweep(tiny(tmp_path, "other", "workers=2", "plots=false"), resume=True, progress=False)


def test_every_preset_runs_in_an_episode() -> None:
    """Each preset's schedule has what the metrics read (a push has a duration, ...), in
    the shortest episode every preset accepts (4.6 s: a push's latest onset, its duration
    and the recovery window), where each one that pushes the arm does work on it."""
    from ptrack_gym.disturbances import PRESETS, preset_does_work
    from train.evaluation.episode import EpisodeSettings, Task, run_episode

    settings = EpisodeSettings("ptrack_gym/TwoLinkTrack-v0", 4.6, 250.0, "on_path", 0.5, 0.01)
    for preset in PRESETS:
        row, _ = run_episode(Task("pd_gravity", preset, 1.0, 0, 0), settings)
        assert row["steps"] == 1150 and np.isfinite(row["path_dist_rms"]), preset
        if preset != "none" and preset_does_work(preset):
            assert row["disturbance_work_j"] != 0.0, preset


def test_recovery_median_counts_episodes_that_never_recovered() -> None:
    from train.evaluation.results import summarize

    rows = pd.DataFrame(
        {
            "controller": "c", "disturbance": "impulse", "level": 1.0, "seed": range(5),
            "episode": 0, "path_dist_rms": 0.1, "failed": 0.0, "time_err_rms": 0.1,
            "speed_ratio_err": 0.0, "tau_rms_frac": 0.1,
            "recovery_s": [0.3, np.nan, np.nan, np.nan, np.nan],
        }
    )  # fmt: skip
    s = summarize(rows, reference=None, resamples=100).iloc[0]
    assert s["recovery_s_median"] == np.inf
    assert s["recovered_frac"] == pytest.approx(0.2)


@pytest.mark.parametrize("method", ["spawn", "fork"])
def test_a_pools_workers_exit_when_the_study_is_killed(method) -> None:
    """A study killed without shutting its pool down (``SIGTERM`` or ``SIGKILL``) leaves no
    worker waiting for work forever: each exits within seconds of its parent."""
    import signal
    import subprocess
    import sys
    import textwrap
    import time
    from pathlib import Path

    script = textwrap.dedent(f"""
        import os, time
        from train.common.runs import worker_pool
        pool = worker_pool(1, {method!r})
        print(pool.submit(os.getpid).result(), flush=True)
        time.sleep(120)
    """)
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(
        [sys.executable, "-c", script], cwd=root, stdout=subprocess.PIPE, text=True
    )
    worker = int(proc.stdout.readline())
    proc.send_signal(signal.SIGKILL)
    proc.wait()

    def alive(pid: int) -> bool:
        try:
            state = Path(f"/proc/{pid}/status").read_text()
        except FileNotFoundError:
            return False
        return "\\nState:\\tZ" not in state  # a zombie has exited

    deadline = time.monotonic() + 20.0
    while alive(worker) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not alive(worker)


def test_a_controller_runs_at_its_own_rates_and_the_record_and_title_say_so(tmp_path) -> None:
    """``controller_rates``: that controller's episodes run its gains with those rates over
    them (the others untouched), its record in config.yml holds them, the title names them."""
    import yaml

    from agents.registry import make_controller
    from train.evaluation.episode import _env

    cfg = tiny(tmp_path, "own", "controller_rates={passivity: {damping_ratio: 0.25}}")
    settings = cfg.settings()
    assert settings.controller_gains("passivity", "two_link") == {"damping_ratio": 0.25}
    assert settings.controller_gains("computed_torque", "two_link") == "default"
    env = _env(settings, "none", 0.0)  # the cache owns it
    own = make_controller("passivity", env, {"damping_ratio": 0.25}).gains
    assert own != make_controller("passivity", env).gains
    out = run_sweep(cfg, progress=False)
    record = yaml.safe_load((out / "config.yml").read_text())["rates"]["two_link"]
    assert record["passivity"]["damping_ratio"] == 0.25
    assert "passivity with {'damping_ratio': 0.25}" in (out / "report.md").read_text()
    plain = numbers(run_sweep(tiny(tmp_path, "plain"), progress=False) / "episodes.csv")
    mine = numbers(out / "episodes.csv")
    ct = mine["controller"] == "computed_torque"
    assert mine[ct].equals(plain[ct])  # the others as they were
    assert not mine[~ct]["path_dist_rms"].equals(plain[~ct]["path_dist_rms"])
