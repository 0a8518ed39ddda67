"""``ptrack probe-authority``: the hand-made residual is paired with its base, is
its base at zero authority and inside its gate's deadband, and acts otherwise."""

from __future__ import annotations

import pytest

from ptrack_gym.errors import InvalidConfigError
from train.studies.authority_probe import main, probe

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
SHORT = {"control_hz": 250.0, "episode_s": 1.0, "seeds": [3, 4]}


def test_zero_authority_is_the_base_exactly() -> None:
    r = probe(TWO_LINK, "passivity", "default", disturbance="periodic:1.0", alpha=0.0,
              gate_rad=None, **SHORT)  # fmt: skip
    assert r.probe_rms == r.base_rms and r.ratio == 1.0


def test_inside_the_deadband_it_is_the_base_and_outside_it_acts() -> None:
    """Undisturbed the default two-link passivity controller stays within 0.5 mrad of the
    path: a 2-mrad deadband keeps the probe off; without a gate it acts."""
    gated = probe(TWO_LINK, "passivity", "tuned", disturbance="none", alpha=10.0,
                  gate_rad=0.002, **SHORT)  # fmt: skip
    assert gated.probe_rms == gated.base_rms
    ungated = probe(TWO_LINK, "passivity", "tuned", disturbance="none", alpha=10.0,
                    gate_rad=None, **SHORT)  # fmt: skip
    assert ungated.base_rms == gated.base_rms  # the same paired base episodes
    assert ungated.probe_rms != ungated.base_rms


def test_cli_prints_one_row_per_condition(capsys) -> None:
    results = main(
        ["--env", TWO_LINK, "--control-hz", "250", "--episode-s", "0.5", "--alpha", "0", "5",
         "--disturbance", "none", "periodic", "--seeds", "1"]
    )  # fmt: skip
    assert [(r.disturbance, r.alpha) for r in results] == [
        ("none", 0.0), ("none", 5.0), ("periodic:1.0", 0.0), ("periodic:1.0", 5.0)
    ]  # fmt: skip
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 + 4 and lines[0].startswith("| disturbance")  # header, rule, rows


def test_a_bad_authority_or_gain_choice_is_refused_before_an_episode_runs() -> None:
    with pytest.raises(InvalidConfigError, match="scale_accel_rad_s2"):
        probe(TWO_LINK, "passivity", "default", disturbance="none", alpha=-1.0,
              gate_rad=None, **SHORT)  # fmt: skip
    with pytest.raises(InvalidConfigError, match="base_gains"):
        probe(TWO_LINK, "passivity", "stiff", disturbance="none", alpha=1.0,
              gate_rad=None, **SHORT)  # fmt: skip
