"""Every entry point reads its config one way (``train.common.arguments.load_config``, what
the command line does without flags): a YAML file of the config's fields updated by
``--set field=value``, each value checked against its annotation; bad input names what is
wrong before anything runs."""

from __future__ import annotations

import dataclasses

import pytest

from ptrack_gym.errors import InvalidConfigError
from train.common.arguments import load_config


@dataclasses.dataclass
class Config:
    seeds: int = 1
    """Seeds."""
    levels: list[float] = dataclasses.field(default_factory=list)
    """Levels."""


def test_a_file_is_updated_by_the_overrides_read_as_yaml(tmp_path) -> None:
    path = tmp_path / "c.yml"
    path.write_text("seeds: 3\nlevels: [0.5]\n")
    assert load_config(Config, path, ["levels=[1, 2.0e-1]"]) == Config(3, [1.0, 0.2])
    assert load_config(Config, None, ["seeds = 7"]) == Config(7)
    (tmp_path / "empty.yml").write_text("")
    assert load_config(Config, tmp_path / "empty.yml", []) == Config()


@pytest.mark.parametrize(
    ("text", "overrides", "match"),
    [
        ("seeds: 3\n", ["seeds"], r"--set expects field=value, got 'seeds'"),
        ("seeds: 3\n", ["=3"], r"--set expects field=value, got '=3'"),
        ("seeds: 3\nepisodes: 2\n", [], r"unknown field\(s\) \['episodes'\] in .*c\.yml"),
        ("seeds: 3\n", ["sedes=4"], r"unknown field\(s\) \['sedes'\] in --set; did you mean"),
        ("- seeds\n- 3\n", [], r"expected a mapping of fields"),
        ("seeds: 3\n", ["seeds=2.5"], r"seeds \(--set\): expected int, got 2\.5"),
        ("levels: 0.5\n", [], r"levels .*expected a list of float"),
    ],
)
def test_bad_input_is_named(tmp_path, text, overrides, match) -> None:
    path = tmp_path / "c.yml"
    path.write_text(text)
    with pytest.raises(InvalidConfigError, match=match):
        load_config(Config, path, overrides)


def test_every_entry_point_reads_its_config_this_way() -> None:
    pytest.importorskip("optuna", reason="the 'tune' extra")
    from train.evaluation import config as evaluate
    from train.studies import adversary, fronts, rates, tune

    for module in (evaluate, tune, fronts, adversary, rates):
        with pytest.raises(InvalidConfigError, match=r"unknown field\(s\) \['nope'\] in --set"):
            module.load_config(None, ["nope=1"])
