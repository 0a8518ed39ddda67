"""Metrics on constructed trajectories with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from ptrack_gym.metrics import (
    EpisodeRecord,
    episode_metrics,
    path_distances,
    phase_offset,
    recovery_time,
    rms,
    speed_ratio,
)
from ptrack_gym.paths import PathProjector, default_path
from ptrack_gym.robots import robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel


@pytest.fixture(scope="module")
def setup():
    model = TwoLinkAnalyticModel()
    projector = PathProjector(default_path(robot_profile("two_link")))
    return model, projector


def shifted_record(tables, lag_s: float, speed: float = 1.0, n_steps: int = 400, dt: float = 0.01):
    """The arm exactly on the path, lag_s behind the reference, moving at ``speed``×."""
    t = dt * np.arange(1, n_steps + 1)
    s_ref = 0.3 + t
    s_arm = 0.3 - lag_s + speed * t
    q, qd, _ = tables.path.evaluate(s_arm)
    return EpisodeRecord(
        t_s=t,
        q=q,
        qd=speed * qd,
        s_ref=s_ref,
        tau_nm=np.zeros_like(q),
        torque_limits_nm=np.array([40.0, 20.0]),
        disturbance_work_j=0.0,
        unstable=False,
    )


def test_time_shifted_path_has_zero_path_distance_and_known_phase_offset(setup) -> None:
    model, tables = setup
    rec = shifted_record(tables, lag_s=0.25)
    m = episode_metrics(rec, model, tables)
    assert m["path_dist_max"] < 1e-9
    assert m["phase_offset_s"] == pytest.approx(-0.25, abs=1e-6)
    assert m["speed_ratio_err"] < 1e-8
    assert m["time_err_rms"] > 0.05  # the time-indexed error sees the lag
    assert m["failed"] == 0.0


def test_speed_ratio_of_a_slow_arm(setup) -> None:
    model, tables = setup
    rec = shifted_record(tables, lag_s=0.0, speed=0.5)
    _, s_star = path_distances(tables, rec.q)
    ratio = speed_ratio(model, tables.path, rec.q, rec.qd, s_star)
    np.testing.assert_allclose(ratio, 0.5, atol=1e-8)


def test_phase_offset_wraps() -> None:
    np.testing.assert_allclose(
        phase_offset(np.array([3.9, 0.1]), np.array([0.1, 3.9]), 4.0), [-0.2, 0.2]
    )


def test_recovery_time_and_rms() -> None:
    t = np.arange(0.0, 5.0, 0.1)
    d = np.where((t >= 1.0) & (t < 2.05), 0.1, 0.001)
    assert recovery_time(t, d, t_end_s=1.5, threshold_rad=0.01) == pytest.approx(0.6)
    assert recovery_time(t, np.full_like(t, 0.001), 1.5, 0.01) == 0.0
    assert np.isnan(recovery_time(t, np.full_like(t, 0.1), 1.5, 0.01))
    assert rms(np.array([3.0, -3.0])) == 3.0


def test_failure_counts_unstable_and_large_distance(setup) -> None:
    model, tables = setup
    rec = shifted_record(tables, lag_s=0.0)
    off = EpisodeRecord(**{**rec.__dict__, "q": rec.q + 0.6})
    assert episode_metrics(off, model, tables)["failed"] == 1.0
    unstable = EpisodeRecord(**{**rec.__dict__, "unstable": True})
    assert episode_metrics(unstable, model, tables)["failed"] == 1.0


def test_an_early_blow_up_never_scores_better_than_tracking(setup) -> None:
    """10 steps on the path, then unstable, out of 400 intended: the missing steps count
    at the failure distance, so the RMS is near it, not near 0."""
    model, tables = setup
    rec = shifted_record(tables, lag_s=0.0, n_steps=10)
    blown = EpisodeRecord(**{**rec.__dict__, "unstable": True, "intended_steps": 400})
    m = episode_metrics(blown, model, tables, failure_distance_rad=0.5)
    assert m["path_dist_rms"] > 0.49
    assert m["time_err_rms"] > 0.49
    assert m["failed"] == 1.0
    assert np.isnan(m["recovery_s"])  # no impulse


def test_a_blow_up_after_an_impulse_never_recovered(setup) -> None:
    """Found by an RL study: a policy that blew up after an impulse crashed the metrics
    (time stamps of the short record against the padded distance series)."""
    model, tables = setup
    rec = shifted_record(tables, lag_s=0.0, n_steps=10)
    blown = EpisodeRecord(
        **{**rec.__dict__, "unstable": True, "intended_steps": 400, "impulse_end_s": 0.02}
    )
    m = episode_metrics(blown, model, tables, failure_distance_rad=0.5)
    assert np.isnan(m["recovery_s"])
    assert m["failed"] == 1.0


def test_effort_and_work(setup) -> None:
    model, tables = setup
    rec = shifted_record(tables, lag_s=0.0)
    tau = np.tile([40.0, 10.0], (len(rec.t_s), 1))
    m = episode_metrics(EpisodeRecord(**{**rec.__dict__, "tau_nm": tau}), model, tables)
    assert m["tau_peak_frac"] == 1.0
    assert m["saturation_frac"] == 1.0
    assert m["tau_rms_frac"] == pytest.approx(np.sqrt((1.0 + 0.25) / 2))
    assert m["controller_work_j"] == pytest.approx(float(np.sum(tau[1:] * np.diff(rec.q, axis=0))))
