"""The headline table ``ptrack evaluate`` and ``make run`` end with: the mean per condition
and controller, undisturbed first, the lowest of each row in bold, trained entrants by
their run folder's name."""

from __future__ import annotations

import pandas as pd

from train.evaluation.results import headline_table


def test_the_headline_table_reads_the_summary() -> None:
    summary = pd.DataFrame(
        {
            "controller": ["a", "a", "sb3:models/x@100", "sb3:models/x@100"],
            "disturbance": ["impulse", "none", "impulse", "none"],
            "level": [1.0, 0.0, 1.0, 0.0],
            "path_dist_rms_mean": [2e-3, 1e-4, 1e-3, 3e-4],
        }
    )
    lines = headline_table(summary, "path_dist_rms").splitlines()
    assert lines[0] == "| condition | a | sb3-x-100 |"
    assert lines[2] == "| undisturbed | **1.00e-04** | 3.00e-04 |"
    assert lines[3] == "| impulse 1 | 2.00e-03 | **1.00e-03** |"
    assert len(lines) == 4


def test_the_headline_states_both_metrics() -> None:
    from train.evaluation.results import headline_tables

    summary = pd.DataFrame(
        {
            "controller": ["a", "b"],
            "disturbance": ["none", "none"],
            "level": [0.0, 0.0],
            "path_dist_rms_mean": [1e-4, 2e-4],
            "time_err_rms_mean": [5e-3, 3e-4],
        }
    )
    text = headline_tables(summary, "path_dist_rms")
    path, time = text.split("Mean time-indexed error")
    assert "Mean path distance (path_dist_rms" in path and "| **1.00e-04** | 2.00e-04 |" in path
    assert "| 5.00e-03 | **3.00e-04** |" in time  # the ranking flips under the other metric
    only = headline_tables(summary.drop(columns="time_err_rms_mean"), "path_dist_rms")
    assert "time-indexed" not in only
