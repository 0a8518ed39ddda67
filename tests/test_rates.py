"""The control-rate study (``ptrack rates``): its config is checked before any
episode, it writes, resumes and refuses like the other studies, a refused rate is a failed
row, and its verdict applies the stated rule."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ptrack_gym.errors import ControlRateError, InvalidConfigError
from train.studies import rates
from train.studies.rates import RatesConfig, load_frame, run_study, verdict_table


def _tiny(out: Path, **kw) -> RatesConfig:
    fields = dict(robots=["two_link"], controllers=["passivity", "computed_torque"],
                  control_rates=[1000.0, 250.0], paths=1, disturbances=["none"],
                  episode_s=0.5, workers=1, out=str(out), plots=False)  # fmt: skip
    return RatesConfig(**{**fields, **kw})


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"robots": ["ur5"]}, "robots: unknown 'ur5'"),
        ({"control_rates": [1000.0, 300.0]}, "300 Hz: 1000 Hz physics"),
        ({"paths": 0}, "paths must be an integer >= 1"),
        ({"controllers": []}, "controllers must be a non-empty list"),
        ({"control_rates": [250.0, 250.0]}, "control_rates has duplicates"),
        ({"gains": "tuned", "robots": ["panda"]}, "no tuned gains for passivity on panda"),
        ({"accuracy_factor": 0.0}, "accuracy_factor must be a positive number"),
    ],
)
def test_bad_configs_are_refused_before_any_episode(
    tmp_path, change, message, without_panda_gains
) -> None:
    cfg = _tiny(tmp_path / "out", **change)
    with pytest.raises(InvalidConfigError, match=message):
        run_study(cfg, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_study_writes_resumes_and_refuses_to_overwrite(tmp_path) -> None:
    out = tmp_path / "study"
    cfg = _tiny(out)
    run_study(cfg, progress=False)
    df = load_frame(out / "episodes.csv")
    assert len(df) == 4 and set(df["control_hz"]) == {1000.0, 250.0}
    assert (df["refused"] == 0).all() and np.isfinite(df["path_dist_rms"]).all()
    report = (out / "report.md").read_text()
    assert "## two_link, none" in report and "## Where each controller holds" in report
    with pytest.raises(InvalidConfigError, match="--resume continues that run"):
        run_study(cfg, progress=False)
    run_study(cfg, resume=True, progress=False)  # nothing left to run
    assert len(load_frame(out / "episodes.csv")) == 4
    with pytest.raises(InvalidConfigError, match="different settings: episode_s"):
        run_study(_tiny(out, episode_s=0.4), resume=True, progress=False)

    # the rows of a controller that ran at other gains: refused, or rerun alone
    import yaml

    saved = yaml.safe_load((out / "config.yml").read_text())
    table = saved["rates"]["two_link"]
    table["passivity"] = {**table["passivity"], "omega": 2.0 * table["passivity"]["omega"]}
    (out / "config.yml").write_text(yaml.safe_dump(saved, sort_keys=False))
    before = (out / "episodes.csv").read_text()
    with pytest.raises(InvalidConfigError, match="gains of passivity on two_link changed"):
        run_study(cfg, resume=True, progress=False)
    assert (out / "episodes.csv").read_text() == before
    run_study(cfg, resume=True, progress=False, rerun_changed=True)
    lines = (out / "episodes.csv").read_text().splitlines()
    assert len(lines) == 5 and all(",passivity," in line for line in lines[-2:])
    again = load_frame(out / "episodes.csv").sort_values(["controller", "control_hz"])
    expect = df.sort_values(["controller", "control_hz"])
    np.testing.assert_array_equal(again["path_dist_rms"], expect["path_dist_rms"])


def test_a_refused_rate_is_a_failed_row_and_does_not_hold(tmp_path, monkeypatch) -> None:
    real = rates.run_episode

    def refuse_slow(task, settings, *args):
        if settings.control_hz < 1000.0 and task.controller == "passivity":
            raise ControlRateError("too slow")
        return real(task, settings, *args)

    monkeypatch.setattr(rates, "run_episode", refuse_slow)
    out = tmp_path / "study"
    run_study(_tiny(out), progress=False)
    df = load_frame(out / "episodes.csv")
    row = df[(df["controller"] == "passivity") & (df["control_hz"] == 250.0)].iloc[0]
    assert row["refused"] == 1 and row["failed"] == 1.0 and np.isnan(row["path_dist_rms"])
    assert "✗" in (out / "report.md").read_text().split("| passivity |")[1].split("\n")[0]


def test_the_verdict_holds_within_the_stated_factor_and_not_beyond() -> None:
    """Holds at rate f iff no failure or refusal and median ≤ factor · (f_ref / f) × the
    median at f_ref: here 3× at 500 Hz and 6× at 250 Hz."""
    cfg = RatesConfig(
        robots=["two_link"], controllers=["a", "b"], control_rates=[1000.0, 500.0, 250.0]
    )
    rows = []
    for ctrl, values in (("a", (1.0, 3.0, 6.0)), ("b", (1.0, 3.01, 1.0))):
        for hz, v in zip(cfg.control_rates, values, strict=True):
            for p in range(3):
                rows.append({"robot": "two_link", "controller": ctrl, "control_hz": hz,
                             "path_seed": p, "disturbance": "none", "seed": 0, "refused": 0,
                             "failed": float(ctrl == "b" and hz == 250.0 and p == 0),
                             "path_dist_rms": v, "time_err_rms": v})  # fmt: skip
    table = verdict_table(cfg, pd.DataFrame(rows)).set_index(["controller", "control_hz"])
    assert table.loc[("a", 500.0), "holds"] and table.loc[("a", 250.0), "holds"]
    assert not table.loc[("b", 500.0), "holds"]  # 3.01× > 3×
    assert not table.loc[("b", 250.0), "holds"]  # a failed episode
