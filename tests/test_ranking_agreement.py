"""Whether two sweeps rank the controllers alike (``ranking_agreement``, ``ptrack report
--against``): leaders, Kendall's τ and the focus controller's place per shared condition."""

from __future__ import annotations

import pandas as pd
import pytest

from train.evaluation.verdict import agreement_table, ranking_agreement


def summary(means: dict[tuple[str, float], dict[str, float]]) -> pd.DataFrame:
    return pd.DataFrame(
        [
            {"controller": c, "disturbance": d, "level": lv, "path_dist_rms_mean": v}
            for (d, lv), row in means.items()
            for c, v in row.items()
        ]
    )


def test_the_same_order_agrees_and_a_reversal_disagrees() -> None:
    a = summary({("impulse", 1.0): {"p": 3.0, "q": 2.0, "r": 1.0},
                 ("noise", 1.0): {"p": 1.0, "q": 2.0, "r": 3.0}})  # fmt: skip
    b = summary({("impulse", 1.0): {"p": 30.0, "q": 20.0, "r": 10.0},  # same order, scaled
                 ("noise", 1.0): {"p": 3.0, "q": 2.0, "r": 1.0},  # reversed
                 ("payload", 1.0): {"p": 1.0, "q": 2.0, "r": 3.0}})  # only in b  # fmt: skip
    agree = ranking_agreement(a, b, "path_dist_rms", focus="p").set_index("condition")
    assert list(agree.index) == ["impulse 1", "noise 1"]  # the shared conditions only
    assert agree.loc["impulse 1", "kendall_tau"] == pytest.approx(1.0)
    assert agree.loc["noise 1", "kendall_tau"] == pytest.approx(-1.0)
    assert agree.loc["impulse 1", "same_leader"] and not agree.loc["noise 1", "same_leader"]
    assert (agree.loc["noise 1", "focus_place_a"], agree.loc["noise 1", "focus_place_b"]) == (1, 3)
    text = agreement_table(agree.reset_index(), ("home", "onset"))
    assert "| noise 1 | p | r | -1.00 | 1 | 3 |" in text
    assert "Same leader in 1 of 2 conditions; Kendall τ mean 0.00, min -1.00." in text


def test_one_swap_of_three_is_tau_one_third() -> None:
    a = summary({("none", 0.0): {"p": 1.0, "q": 2.0, "r": 3.0}})
    b = summary({("none", 0.0): {"p": 2.0, "q": 1.0, "r": 3.0}})
    agree = ranking_agreement(a, b, "path_dist_rms")
    assert agree.loc[0, "kendall_tau"] == pytest.approx(1 / 3)
    assert agree.loc[0, "condition"] == "undisturbed" and "focus_place_a" not in agree


def test_sweeps_with_nothing_in_common_are_refused() -> None:
    a = summary({("impulse", 1.0): {"p": 1.0, "q": 2.0}})
    with pytest.raises(ValueError, match="share no condition"):
        ranking_agreement(a, summary({("noise", 1.0): {"p": 1.0, "q": 2.0}}), "path_dist_rms")
    with pytest.raises(ValueError, match="fewer than 2 shared controllers"):
        ranking_agreement(a, summary({("impulse", 1.0): {"p": 1.0, "x": 2.0}}), "path_dist_rms")
