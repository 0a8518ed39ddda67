"""Error-vs-effort fronts (``train.studies.fronts``): the front is the non-dominated set and falls
monotonically, the common-effort reading interpolates on it and never extrapolates, and a
tiny sweep runs, resumes after a cut line and refuses bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ptrack_gym.errors import InvalidConfigError
from train.common.statistics import pareto_front
from train.studies.fronts import FrontConfig, common_effort_table, error_at, run_fronts


def test_front_keeps_exactly_the_non_dominated_points_by_rising_effort():
    effort = np.array([3.0, 1.0, 2.0, 2.5, 4.0, 1.5, np.nan])
    error = np.array([0.2, 1.0, 0.5, 0.6, 0.2, 1.2, 0.01])
    idx = pareto_front(effort, error)
    assert idx.tolist() == [1, 2, 0]  # 1.5/1.2, 2.5/0.6 and 4.0/0.2 are dominated; NaN ignored
    assert np.all(np.diff(effort[idx]) > 0) and np.all(np.diff(error[idx]) < 0)
    rng = np.random.default_rng(0)
    for _ in range(20):  # any cloud: the front is monotone and nothing beats a front point
        e, r = rng.uniform(0, 1, 30), rng.uniform(0, 1, 30)
        f = pareto_front(e, r)
        assert np.all(np.diff(e[f]) > 0) and np.all(np.diff(r[f]) < 0)
        for i in f:
            assert not np.any((e < e[i]) & (r < r[i]))


def test_error_at_interpolates_log_log_on_the_front_and_never_extrapolates():
    effort = np.array([1.0, 4.0, 2.0])
    error = np.array([1.0, 0.25, 10.0])  # (2, 10) is dominated by (1, 1)
    assert error_at(effort, error, 2.0) == pytest.approx(0.5)  # geometric midpoint
    assert error_at(effort, error, 1.0) == pytest.approx(1.0)
    assert math.isnan(error_at(effort, error, 0.5))
    assert math.isnan(error_at(effort, error, 5.0))
    assert math.isnan(error_at(effort, error, float("nan")))


def test_common_effort_table_reads_each_front_at_the_reference_effort():
    rows = [
        {"controller": c, "scale": k, "panel": "impulse", "effort": eff, "error_rad": err}
        for c, k, eff, err in [
            ("ref", 0.5, 1.0, 2.0), ("ref", 1.0, 2.0, 1.0), ("ref", 2.0, 4.0, 0.5),
            ("a", 0.5, 1.0, 0.4), ("a", 1.0, 4.0, 0.1),
            ("b", 1.0, 3.0, 0.1), ("b", 2.0, 5.0, 0.05),
        ]
    ]  # fmt: skip
    text, found = common_effort_table(rows, "ref")
    assert found["impulse"]["ref"] == pytest.approx(1.0)
    assert found["impulse"]["a"] == pytest.approx(0.2)  # log-log midpoint of 0.4 and 0.1
    assert math.isnan(found["impulse"]["b"])  # b's front starts above the common effort
    assert "| impulse | 2.0000 | 0.2 | — | 1 |" in text


TINY = dict(
    env_id="ptrack_gym/TwoLinkTrack-v0",
    controllers=["computed_torque", "pd_gravity"],
    gains="default",
    scales=[0.5, 1.0, 2.0],
    disturbances=["none", "periodic"],
    seeds=2,
    episode_s=0.5,
    control_hz=250.0,
    workers=1,
)


def test_a_tiny_sweep_runs_and_resumes_after_a_cut_line(tmp_path):
    out = run_fronts(FrontConfig(**TINY, out=str(tmp_path / "f")), progress=False)
    lines = (out / "points.csv").read_text().splitlines()
    assert len(lines) == 1 + 2 * 3 * 2 * 2
    for name in ("fronts.csv", "fronts.png", "common_effort.md"):
        assert (out / name).stat().st_size > 0
    # PD + gravity loses tracking as its gains soften, undisturbed (a physical sanity check)
    import csv

    rows = [r for r in csv.DictReader((out / "fronts.csv").open())
            if r["controller"] == "pd_gravity" and r["panel"] == "none"]  # fmt: skip
    errors = [float(r["error_rad"]) for r in sorted(rows, key=lambda r: float(r["scale"]))]
    assert errors[0] > errors[1] > errors[2]

    with pytest.raises(InvalidConfigError, match="--resume"):
        run_fronts(FrontConfig(**TINY, out=str(out)), progress=False)
    cut = "\n".join(lines[:-2]) + "\n" + lines[-2][:10]  # the last episode lost, one cut
    (out / "points.csv").write_text(cut)
    run_fronts(FrontConfig(**TINY, out=str(out)), resume=True, progress=False)
    again = {tuple(line.split(",")) for line in (out / "points.csv").read_text().splitlines()}
    assert again == {tuple(line.split(",")) for line in lines}  # the same numbers


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("scales", [0.5, 2.0], "1.0"),
        ("scales", [1.0, -1.0], "positive"),
        ("controllers", ["lqr"], "controllers"),
        ("reference", "slotine_li", "reference"),
        ("gains", "best", "gains"),
        ("seeds", 1, "seeds"),
        ("disturbances", ["quake"], "disturbances"),
    ],
)
def test_bad_input_is_refused_before_any_episode(tmp_path, field, value, match):
    with pytest.raises(InvalidConfigError, match=match):
        run_fronts(FrontConfig(**{**TINY, field: value}, out=str(tmp_path / "f")))
    assert not (tmp_path / "f").exists()
