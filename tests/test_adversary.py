"""The adversarial disturbance search (``ptrack adversary``) on a tiny budget: it
finds a worse push than the median random one, a found worst case replays bit-identically
from its spec, a search resumes, and bad input is refused before any episode runs."""

from __future__ import annotations

import pytest

pytest.importorskip("optuna", reason="the optional 'tune' extra (Optuna) is not installed")
pytest.importorskip("cmaes", reason="the optional 'tune' extra (cmaes) is not installed")

import pandas as pd
import yaml

from ptrack_gym.errors import InvalidConfigError
from train.cli import run_command
from train.studies.adversary import AdversaryConfig, load_config, replay, run_search

#: Two-link, short episodes: impulses in [0.2, 0.6] s, cost over the 0.5 s after.
TINY = [
    "env_id=ptrack_gym/TwoLinkTrack-v0",
    "controllers=[pd_gravity]",
    "energies_j=[0.6]",
    "onset_s=[0.2, 0.6]",
    "post_s=0.5",
    "popsize=4",
    "workers=2",
]


def main(argv: list[str]) -> int:
    """``ptrack adversary`` with ``argv``."""
    return run_command("adversary", argv)


@pytest.fixture(scope="module")
def search(tmp_path_factory):
    out = tmp_path_factory.mktemp("adv") / "run"
    cfg = load_config(None, [*TINY, "budget=16", f"out={out}"])
    run_search(cfg, progress=False)
    return out


def test_search_finds_a_worse_push_than_the_median_random_one(search) -> None:
    df = pd.read_csv(search / "trials.csv", float_precision="round_trip")
    assert len(df) == 32  # 16 searched + 16 random
    searched = df[df["kind"] == "search"]["cost_rad"]
    random = df[df["kind"] == "random"]["cost_rad"]
    assert searched.max() > random.median()
    assert (df["work_j"] > 0).any()  # the delivered work is recorded
    summary = pd.read_csv(search / "summary.csv", float_precision="round_trip")
    assert summary.loc[0, "worst_search_rad"] == searched.max()
    assert summary.loc[0, "median_random_rad"] == random.median()
    assert summary.loc[0, "worst_rad"] == df["cost_rad"].max()  # searched or random
    worst = yaml.safe_load((search / "worst.yml").read_text())["worst"]
    for (controller, energy), g in df.groupby(["controller", "energy_j"]):
        entry = worst[controller]["impulse"][f"{energy:g}"]
        assert entry["cost_rad"] == g["cost_rad"].max()  # the worst episode run, either kind
        assert entry["found_by"] == g.loc[g["cost_rad"].idxmax(), "kind"]
    for name in ("summary.md", "adversary.png", "worst.yml", "config.yml", "optuna.journal"):
        assert (search / name).stat().st_size > 0, name


def test_worst_case_replays_bit_identically(search) -> None:
    worst = yaml.safe_load((search / "worst.yml").read_text())
    entry = worst["worst"]["pd_gravity"]["impulse"]["0.6"]
    outcome = replay(search / "worst.yml", "pd_gravity", "impulse", 0.6)
    assert outcome.cost == entry["cost_rad"]  # exactly
    assert outcome.work_j == entry["work_j"]


def test_search_resumes_to_its_budget_without_repeating(search, tmp_path) -> None:
    import shutil

    out = tmp_path / "resumed"
    shutil.copytree(search, out)
    with pytest.raises(InvalidConfigError, match="--resume"):
        run_search(load_config(None, [*TINY, "budget=20", f"out={out}"]), progress=False)
    with pytest.raises(InvalidConfigError, match="different settings"):
        run_search(load_config(None, [*TINY, "budget=20", "seed=3", f"out={out}"]), resume=True)
    run_search(load_config(None, [*TINY, "budget=20", f"out={out}"]), resume=True, progress=False)
    df = pd.read_csv(out / "trials.csv", float_precision="round_trip")
    assert len(df) == 40
    # the random draws of the resumed search are those of an uninterrupted one
    fresh = tmp_path / "fresh"
    run_search(load_config(None, [*TINY, "budget=20", f"out={fresh}"]), progress=False)
    whole = pd.read_csv(fresh / "trials.csv", float_precision="round_trip")
    rand = ["trial", "cost_rad", "spec"]
    pd.testing.assert_frame_equal(
        df[df["kind"] == "random"][rand].sort_values("trial").reset_index(drop=True),
        whole[whole["kind"] == "random"][rand].sort_values("trial").reset_index(drop=True),
    )
    first = pd.read_csv(search / "trials.csv", float_precision="round_trip")
    kept = df[df["trial"] < 16].sort_values(["kind", "trial"]).reset_index(drop=True)
    pd.testing.assert_series_equal(
        kept["cost_rad"], first.sort_values(["kind", "trial"]).reset_index(drop=True)["cost_rad"]
    )


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("energies_j=[-1.0]", "energies_j"),
        ("families=[]", "families"),
        ("families=[earthquake]", "families"),
        ("budget=0", "budget"),
        ("budget=9", r"budget must be >= 10 \(the search starts from the best tenth"),
        ("controllers=[lqr]", "controllers"),
        ("push_links=[no_such_link]", "no link 'no_such_link'"),
        ("energy_mode=kinetic", "energy_mode"),
        ("onset_s=[2.0, 1.0]", "onset_s"),
        ("gains=fancy", "gains"),
    ],
)
def test_bad_input_is_refused_before_any_episode(tmp_path, override, match, capsys) -> None:
    extra = ["families=[push]"] if "push_links" in override else []
    cfg = load_config(None, [*TINY, "budget=10", *extra, override, f"out={tmp_path / 'x'}"])
    with pytest.raises(InvalidConfigError, match=match):
        run_search(cfg, progress=False)
    assert not (tmp_path / "x").exists()
    with pytest.raises(SystemExit) as exc:
        main([*[a for t in [*TINY, *extra, override] for a in ("--set", t)],
              "--out", str(tmp_path / "y")])  # fmt: skip
    assert exc.value.code == 2
    assert not (tmp_path / "y").exists()


def test_tuned_gains_that_do_not_exist_are_refused_before_any_episode(
    tmp_path, monkeypatch
) -> None:
    import agents.registry

    monkeypatch.setattr(agents.registry, "TUNED_DIR", tmp_path / "none")
    cfg = load_config(None, [*TINY, "budget=10", "gains=tuned", f"out={tmp_path / 'x'}"])
    with pytest.raises(InvalidConfigError, match="no tuned gains for pd_gravity"):
        run_search(cfg, progress=False)
    assert not (tmp_path / "x").exists()


def test_unknown_config_keys_are_refused() -> None:
    with pytest.raises(InvalidConfigError, match=r"unknown field\(s\) \['budjet'\]"):
        load_config(None, ["budjet=3"])
    assert isinstance(load_config(None, []), AdversaryConfig)
