"""The periodic torque's frequency scan (train/studies/periodic_scan.py): its geometry
(sphere angles, directions ↔ amplitude weights), its optimiser, its superposition on
synthetic data and on the real closed loop in the linear range, and the scan as a run of
the adversarial search (resumable, verified episodes recorded)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from train.studies.periodic_scan import (
    direction_for,
    predicted_cost,
    quadratic,
    scan_frequencies,
    scan_task,
    sphere_angles,
    top_frequencies,
    worst_weights,
)
from train.studies.worst_case import ANGLE_RANGE, sphere_point


def test_sphere_angles_invert_sphere_point() -> None:
    rng = np.random.default_rng(0)
    for d in range(2, 8):
        for x in [*np.eye(d), -np.eye(d)[d - 1], *rng.normal(size=(20, d))]:
            angles = sphere_angles(x)
            assert len(angles) == d - 1
            assert all(ANGLE_RANGE[0] <= a <= ANGLE_RANGE[1] for a in angles)
            np.testing.assert_allclose(sphere_point(angles), x / np.linalg.norm(x), atol=1e-12)
    for bad in ([0.0, 0.0], [1.0], [math.nan, 1.0]):
        with pytest.raises(ValueError, match="nonzero"):
            sphere_angles(bad)


def test_scan_frequencies_are_log_spaced_inside_the_range() -> None:
    f = scan_frequencies((0.1, 30.0), 24)
    assert len(f) == 24 and 0.1 < f[0] and f[-1] < 30.0
    np.testing.assert_allclose(np.diff(np.log(f)), np.log(300.0) / 24)
    assert f[0] / 0.1 == pytest.approx(30.0 / f[-1])  # half a cell from each bound


def test_a_direction_for_weights_gives_those_weights() -> None:
    rng = np.random.default_rng(1)
    limits = np.array([50.0, 50.0, 32.0, 32.0, 32.0, 20.0])
    for _ in range(10):
        w = np.abs(rng.normal(size=6))
        w /= np.linalg.norm(w)
        x = direction_for(w, limits)
        amp = limits * np.abs(x)  # the family's amplitude weights (PeriodicTorque)
        np.testing.assert_allclose(amp / np.linalg.norm(amp), w, atol=1e-12)
        assert np.linalg.norm(x) == pytest.approx(1.0)


def test_the_quadratic_is_the_cost_of_superposed_errors() -> None:
    """On exactly linear data the prediction is the RMS of e₀ + Σ w_k (e_k − e₀)."""
    rng = np.random.default_rng(2)
    base = rng.normal(size=(50, 3)) * 0.01
    axes = [base + rng.normal(size=(50, 3)) for _ in range(3)]
    q_form, b, c = quadratic(base, axes)
    for _ in range(5):
        w = np.abs(rng.normal(size=3))
        w /= np.linalg.norm(w)
        errors = base + sum(wk * (ek - base) for wk, ek in zip(w, axes, strict=True))
        direct = math.sqrt(np.mean(np.sum(errors**2, axis=1)))
        assert predicted_cost(q_form, b, c, w) == pytest.approx(direct, rel=1e-12)


def test_worst_weights_beat_random_weights_and_find_a_nonnegative_top_mode() -> None:
    rng = np.random.default_rng(3)
    for n in (2, 4, 7):
        a = rng.normal(size=(n, n))
        q_form, b, c = a @ a.T, rng.normal(size=n) * 0.1, 0.05
        w, best = worst_weights(q_form, b, c)
        assert np.all(w >= 0) and np.linalg.norm(w) == pytest.approx(1.0)
        assert best == pytest.approx(predicted_cost(q_form, b, c, w))
        samples = np.abs(rng.normal(size=(5000, n)))
        samples /= np.linalg.norm(samples, axis=1, keepdims=True)
        assert best >= max(predicted_cost(q_form, b, c, s) for s in samples) - 1e-9
    v = np.array([0.6, 0.8, 0.0])  # a non-negative top eigenvector, no linear term
    q_form = 5.0 * np.outer(v, v) + np.diag([0.1, 0.2, 0.3])
    w, _ = worst_weights(q_form, np.zeros(3), 0.0)
    top = np.linalg.eigh(q_form)[1][:, -1]
    np.testing.assert_allclose(w, np.abs(top), atol=1e-6)


def test_top_frequencies_take_the_grids_peaks_first() -> None:
    predicted = [1.0, 3.0, 2.0, 2.5, 5.0, 4.9, 0.5]
    assert top_frequencies(predicted, 2) == [4, 1]  # the peaks 5.0 and 3.0, not 4.9
    assert top_frequencies(predicted, 4) == [4, 1, 5, 3]  # the peaks, then the rest
    assert top_frequencies([2.0, 1.0], 5) == [0, 1]


def test_the_prediction_holds_on_the_closed_loop_in_its_linear_range() -> None:
    """Two-link, the passivity controller, a 6-mJ periodic torque near its resonance: the
    prediction from one undisturbed and two axis episodes equals real episodes within 1 %
    (at the worst weights and at random ones) — the superposition, the error vectors and
    the direction ↔ weights map are right."""
    from train.studies.adversary_config import AdversaryConfig
    from train.studies.worst_case import Searchable, evaluate

    cfg = AdversaryConfig(env_id="ptrack_gym/TwoLinkTrack-v0", controllers=["passivity"],
                          families=["periodic"], energies_j=[0.006], periodic_s=4.0,
                          post_s=1.5)  # fmt: skip
    target = Searchable(cfg, "periodic", 0.006)
    s0, f = 0.3 * target.period_s, 3.9
    window = target.window({})

    def task(spec):
        return (cfg.env_id, "passivity", spec, 0, target.episode_s(), window, 1000.0, 0.5,
                "default", s0)  # fmt: skip

    base = scan_task(task(None))[1]
    axes = [
        scan_task(task(target.spec({"frequency_hz": f, "direction": list(e)})))[1]
        for e in np.eye(2)
    ]
    q_form, b, c = quadratic(base, axes)
    w, best = worst_weights(q_form, b, c)
    limits = np.array(target.torque_limits_nm)
    for weights in (w, np.array([0.6, 0.8]), np.array([0.96, 0.28])):
        spec = target.spec({"frequency_hz": f, "direction": list(direction_for(weights, limits))})
        real = evaluate(*task(spec)).cost
        assert predicted_cost(q_form, b, c, weights) == pytest.approx(real, rel=0.01)
    assert best >= predicted_cost(q_form, b, c, np.array([0.6, 0.8]))


SCAN = [
    "env_id=ptrack_gym/TwoLinkTrack-v0",
    "controllers=[passivity]",
    "families=[periodic]",
    "energies_j=[0.3]",
    "frequency_hz=[0.5, 8.0]",
    "periodic_s=2.0",
    "post_s=0.5",
    "budget=10",
    "popsize=4",
    "restarts=0",
    "polish_budget=0",
    "scan_points=4",
    "scan_top=2",
    "scan_phases=2",
    "search_seeds=[0]",
    "control_hz=250.0",
    "workers=1",
]


def test_the_scan_runs_in_the_search_and_resumes_without_repeating(tmp_path, monkeypatch) -> None:
    """Per seed: the random draws, then 4 frequencies × 2 axis episodes, 2 more start
    phases × 2 axis episodes at the frequency predicted worst, 2 + 1 verified ones
    (recorded with their prediction), then the CMA-ES run; a scan interrupted after two
    frequencies resumes where it stopped, and a finished search runs nothing again."""
    pytest.importorskip("optuna", reason="the optional 'tune' extra is not installed")
    import optuna
    import pandas as pd
    import yaml
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    import train.studies.periodic_scan as periodic_scan
    from train.studies.adversary import load_config, run_search, study_name

    out = tmp_path / "scan"
    real, calls = periodic_scan._axis_params, []

    def interrupted(*args):
        calls.append(args)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(periodic_scan, "_axis_params", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_search(load_config(None, [*SCAN, f"out={out}"]), progress=False)
    monkeypatch.setattr(periodic_scan, "_axis_params", real)
    run_search(load_config(None, [*SCAN, f"out={out}"]), resume=True, progress=False)

    df = pd.read_csv(out / "trials.csv")
    assert list(df["run"].drop_duplicates()) == ["random", "scan", "search0"]
    assert len(df) == 10 + (4 * 2 + 2 * 2 + 2 + 1) + 10
    scan = df[df["run"] == "scan"]
    freqs = [yaml.safe_load(spec)["frequency_hz"] for spec in scan["spec"]]
    grid = scan_frequencies((0.5, 8.0), 4)
    for f in grid:  # each frequency's two axis episodes, once each
        assert sum(math.isclose(x, f) for x in freqs[:8]) == 2
    s0 = scan["s0"].to_numpy()
    assert len(set(s0[:8])) == 1  # the first stage: one start phase
    assert len(set(s0[8:12])) == 2 and s0[0] not in set(s0[8:12])  # two more
    assert len(set(freqs[8:12])) == 1 and any(math.isclose(freqs[8], f) for f in grid)
    storage = JournalStorage(JournalFileBackend(str(out / "optuna.journal")))
    study = optuna.load_study(
        study_name=study_name("passivity", "periodic", 0.3, "scan", 0), storage=storage
    )
    verified = [study.user_attrs[key] for key in ("verified0", "verified1", "verified_phase")]
    assert [v["frequency_hz"] for v in verified] == pytest.approx(freqs[12:])
    assert verified[2]["frequency_hz"] == pytest.approx(freqs[8])  # the second stage's
    assert any(math.isclose(verified[2]["start_phase"] * 4.0, x) for x in s0[8:12])
    for v, cost in zip(verified, scan["cost_rad"].iloc[12:], strict=True):
        assert any(math.isclose(v["frequency_hz"], f) for f in grid)
        assert v["predicted_cost"] > 0 and len(v["weights"]) == 2 and cost > 0
    before = len(study.trials)
    run_search(load_config(None, [*SCAN, f"out={out}"]), resume=True, progress=False)
    assert len(study.trials) == before == 15  # nothing run again, nothing lost


def test_golden_max_finds_a_peak_narrower_than_the_grid() -> None:
    """A Lorentzian of half-width 0.005 in a bracket of width 1 (a lightly damped resonance
    between two grid points): 20 probes land within 0.002 of its top, each probe once,
    never worse than the start; the same values give the same probes (a resume)."""
    from train.studies.periodic_scan import golden_max

    def peak(x: float) -> float:
        return 1.0 / (1.0 + ((x - 0.3712) / 0.005) ** 2)

    probed: list[tuple[int, float]] = []

    def evaluate(k: int, x: float) -> float:
        probed.append((k, x))
        return peak(x)

    x, fx = golden_max(0.0, 0.5, 1.0, peak(0.5), evaluate, 20)
    assert abs(x - 0.3712) < 0.002 and fx == peak(x) and fx > 0.9
    assert [k for k, _ in probed] == list(range(20))
    assert all(0.0 < p < 1.0 for _, p in probed)
    again: list[tuple[int, float]] = []
    golden_max(0.0, 0.5, 1.0, peak(0.5), lambda k, u: again.append((k, u)) or peak(u), 20)
    assert again == probed
    flat, value = golden_max(0.0, 0.5, 1.0, 2.0, lambda k, u: 1.0, 5)  # nothing better
    assert (flat, value) == (0.5, 2.0)


def test_grid_bracket_takes_the_neighbours_or_the_range() -> None:
    from train.studies.periodic_scan import grid_bracket

    grid = scan_frequencies((0.5, 8.0), 4)
    assert grid_bracket(grid, 0, (0.5, 8.0)) == (0.5, grid[1])
    assert grid_bracket(grid, 2, (0.5, 8.0)) == (grid[1], grid[3])
    assert grid_bracket(grid, 3, (0.5, 8.0)) == (grid[2], 8.0)


def test_the_refined_scan_verifies_refined_frequencies_and_phases_at_two(tmp_path) -> None:
    """``scan_refine=2``, ``scan_phase_top=2``, ``scan_phase_refine=2``: per chosen
    frequency two probes inside its grid neighbours, the verified episode at the best of the
    three (by prediction); the second stage at the two worst, each refined by two probes at
    its worst start phase; the episode count is ``run_budget``'s; a finished search runs
    nothing again."""
    pytest.importorskip("optuna", reason="the optional 'tune' extra is not installed")
    import optuna
    import pandas as pd
    import yaml
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from train.studies.adversary import load_config, run_budget, run_search, study_name

    out = tmp_path / "refined"
    args = [*SCAN, "scan_refine=2", "scan_phase_top=2", "scan_phase_refine=2", f"out={out}"]
    cfg = load_config(None, args)
    run_search(cfg, progress=False)
    df = pd.read_csv(out / "trials.csv")
    scan = df[df["run"] == "scan"]
    assert len(scan) == run_budget(cfg, "scan", 2) == 4 * 2 + 2 + 2 * 2 * 2 + (2 * 2 + 1 + 4) * 2
    storage = JournalStorage(JournalFileBackend(str(out / "optuna.journal")))
    study = optuna.load_study(
        study_name=study_name("passivity", "periodic", 0.3, "scan", 0), storage=storage
    )
    attrs = study.user_attrs
    grid = scan_frequencies((0.5, 8.0), 4)
    freqs = [yaml.safe_load(spec)["frequency_hz"] for spec in scan["spec"]]
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(complete) == len(study.trials) == run_budget(cfg, "scan", 2)  # none cut off
    from train.studies.periodic_scan import top_frequencies, worst_weights

    def predicted(key: str) -> float:  # a point's predicted worst cost, from its record
        form = attrs[key]
        if form["unstable"]:
            return cfg.failure_distance_rad
        return worst_weights(np.array(form["q"]), np.array(form["b"]), form["c"])[1]

    chosen = top_frequencies([predicted(f"scan{i}") for i in range(4)], 2)
    for j in range(2):
        assert f"refine{j}_0" in attrs and f"refine{j}_1" in attrs
        keys = [f"scan{chosen[j]}", f"refine{j}_0", f"refine{j}_1"]
        best = max(predicted(key) for key in keys)  # the verified point: the best of three
        assert attrs[f"verified{j}"]["predicted_cost"] == pytest.approx(best, rel=1e-12)
        probes = freqs[8 + 4 * j : 8 + 4 * (j + 1)]  # two probes x two joints
        assert not any(math.isclose(p, g) for p in probes for g in grid)
        assert all(0.5 < p < 8.0 for p in probes)
        v = attrs[f"verified{j}"]
        assert any(math.isclose(v["frequency_hz"], f) for f in [*grid, *probes])
    # each second stage, refined in frequency at its worst start phase: the verified point
    # is the best of that phase's point and its two probes, from that phase
    for t, (tag, verified) in enumerate([("", "verified_phase"), ("1_", "verified_phase1")]):
        phase_keys = [f"phase{tag}{m}" for m in range(2)]
        worst_phase = max(phase_keys, key=predicted)
        keys = [worst_phase, f"rephase{t}_0", f"rephase{t}_1"]
        assert attrs[verified]["predicted_cost"] == pytest.approx(
            max(predicted(k) for k in keys), rel=1e-12
        )
    stages = [attrs["verified_phase"], attrs["verified_phase1"]]
    assert stages[0]["frequency_hz"] != stages[1]["frequency_hz"]
    assert all(0.5 <= s["frequency_hz"] <= 8.0 for s in stages)
    assert stages[0]["predicted_cost"] > 0 and stages[1]["predicted_cost"] > 0
    before = len(study.trials)
    run_search(load_config(None, args), resume=True, progress=False)
    assert len(study.trials) == before


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("scan_refine=-1", "scan_refine must be an integer >= 0"),
        ("scan_phase_top=0", r"scan_phase_top must lie in \[1, scan_top = 2\]"),
        ("scan_phase_top=3", r"scan_phase_top must lie in \[1, scan_top = 2\]"),
        ("scan_top=5", r"scan_top \(5\) must not exceed scan_points \(4\)"),
        ("scan_points=2", "scan_points >= 3"),
        ("scan_top=0", "scan_top >= 1"),
        ("scan_points=-1", "scan_points must be an integer"),
        ("scan_top=-2", "scan_top must be an integer >= 0"),
    ],
)
def test_a_bad_scan_is_refused_before_any_episode(override, match) -> None:
    from ptrack_gym.errors import InvalidConfigError
    from train.studies.adversary import load_config

    cfg = load_config(None, [*SCAN, override])
    with pytest.raises(InvalidConfigError, match=match):
        cfg.validate()
    box = load_config(None, [*SCAN, "space=box"])
    with pytest.raises(InvalidConfigError, match="needs space 'period'"):
        box.validate()


def test_only_a_periodic_torque_is_scanned_and_old_searches_load_without_a_scan() -> None:
    from train.studies.adversary import kinds, load_config, run_budget
    from train.studies.adversary_config import saved_config

    cfg = load_config(None, SCAN)
    assert kinds(cfg, "periodic") == ["random", "scan", "search0"]
    assert kinds(cfg, "impulse") == kinds(cfg, "push") == ["random", "search0"]
    assert run_budget(cfg, "scan", 7) == 4 * 7 + 2 + 2 * 7 + 1
    refined = load_config(None, [*SCAN, "scan_refine=3", "scan_phase_top=2"])
    assert run_budget(refined, "scan", 7) == 4 * 7 + 2 + 3 * 7 * 2 + (2 * 7 + 1) * 2
    assert saved_config({"env_id": "ptrack_gym/TwoLinkTrack-v0"}).scan_refine == 0
    assert saved_config({"env_id": "ptrack_gym/TwoLinkTrack-v0"}).scan_points == 0
