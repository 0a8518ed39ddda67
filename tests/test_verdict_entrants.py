"""The verdict's summary of an entrant group over its seeds (issue 39: the spread over
seeds, the IQM over seeds, and which seed a model card ships), on hand-made tables."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from train.studies.verdict_entrants import (
    entrant_group,
    representative_seed,
    seed_groups,
    seed_groups_markdown,
)


def test_a_runs_group_is_its_folder_without_the_seed_suffix() -> None:
    assert entrant_group("sb3:runs/x/residual-passivity_s3") == "residual-passivity"
    assert entrant_group("sb3:runs/x/residual-passivity-tank_s12@40000") == (
        "residual-passivity-tank"
    )
    assert entrant_group("sb3:models/sac_pure_twolink") == "sac_pure_twolink"
    assert entrant_group("sb3:runs/x/a_s1b/") == "a_s1b"  # only a trailing _s<digits>


def _table(ratios: dict[str, list[float]], marks: dict[str, list[str]]) -> pd.DataFrame:
    rows = []
    for name, rs in ratios.items():
        for k, (r, m) in enumerate(zip(rs, marks[name], strict=True)):
            rows.append({"robot": "two_link", "reference": "passivity", "controller": name,
                         "disturbance": ["none", "push"][k], "level": float(k),
                         "metric": "path_dist_rms", "ratio": r, "mark": m})  # fmt: skip
    return pd.DataFrame(rows)


def test_seed_groups_take_the_iqm_range_and_marks_over_seeds() -> None:
    seeds = [f"sb3:runs/c/res_s{k}" for k in range(5)]
    none = [0.9, 1.0, 1.1, 1.3, 5.0]
    push = [0.5, 0.6, 0.7, 0.8, 0.9]
    table = _table(
        {s: [a, b] for s, a, b in zip(seeds, none, push, strict=True)},
        {
            s: ["better", "unresolved"] if k < 2 else ["worse", "better"]
            for k, s in enumerate(seeds)
        },
    )
    episodes = pd.DataFrame({
        "robot": "two_link", "controller": [seeds[0], seeds[4], seeds[4], "passivity"],
        "disturbance": ["none", "none", "push", "none"], "level": [0.0, 0.0, 1.0, 0.0],
        "failed": [1, 2, 0, 7],
    })  # fmt: skip
    groups = seed_groups(table, episodes).set_index("disturbance")
    assert set(groups["group"]) == {"res"} and (groups["seeds"] == 5).all()
    assert groups.loc["none", "iqm_ratio"] == pytest.approx(stats.trim_mean(none, 0.25))
    assert groups.loc["push", "iqm_ratio"] == pytest.approx(np.mean(push[1:4]))
    assert (groups.loc["none", "min_ratio"], groups.loc["none", "max_ratio"]) == (0.9, 5.0)
    assert (groups.loc["none", "better"], groups.loc["none", "worse"]) == (2, 3)
    assert (groups.loc["push", "better"], groups.loc["push", "worse"]) == (3, 0)
    assert groups.loc["none", "failed"] == 3 and groups.loc["push", "failed"] == 0
    text = seed_groups_markdown(groups.reset_index())
    assert "| two_link | res | passivity |" in text and "| 2 / 3 | 3 |" in text
    # geometric means over the two conditions: seed 2 (√(1.1·0.7)) is the median of five
    assert representative_seed(table, "res") == seeds[2]


def test_the_shipped_seed_is_the_lower_median_and_no_table_gives_no_groups() -> None:
    seeds = [f"sb3:runs/c/g_s{k}" for k in range(4)]
    table = _table({s: [r, r] for s, r in zip(seeds, [4.0, 1.0, 3.0, 2.0], strict=True)},
                   {s: ["unresolved"] * 2 for s in seeds})  # fmt: skip
    assert representative_seed(table, "g") == seeds[3]  # ratios 1, 2, 3, 4: the lower median
    assert seed_groups(pd.DataFrame(), pd.DataFrame()).empty
    assert seed_groups_markdown(pd.DataFrame()) == ""


def test_the_protocol_table_of_a_run_that_is_not_here_says_so(tmp_path) -> None:
    from train.evaluation.protocol import protocol_markdown, protocol_section

    gone = f"sb3:{tmp_path / 'gone'}"
    assert f"| {gone} | – | – | – | – | (its run folder is not here) | – | – | – |" in (
        protocol_markdown([gone])
    )
    assert protocol_section(["passivity", "pd_gravity"]) == []


def test_the_protocol_table_names_the_gate_a_run_is_deployed_behind() -> None:
    from train.evaluation.protocol import protocol_markdown

    row = protocol_markdown(["sb3:models/sac_residual_passivity_twolink_gated"]).splitlines()[-1]
    assert row.endswith("| a gate of 2 mrad past a 2-mrad deadband |"), row
    assert "| 60000 |" in row  # a shipped model without checkpoints: its run's steps
    row = protocol_markdown(["sb3:models/sac_residual_passivity_twolink"]).splitlines()[-1]
    assert row.endswith("| – |"), row
