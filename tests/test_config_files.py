"""Every entry point reads its config one way (``train.config_files``): a YAML file of the
config's fields updated by ``--set key=value``; bad input names what is wrong before
anything runs."""

from __future__ import annotations

import dataclasses

import pytest

from ptrack_gym.errors import InvalidConfigError
from train.config_files import config_data, parse_set


@dataclasses.dataclass
class Config:
    seeds: int = 1
    levels: list[float] = dataclasses.field(default_factory=list)


def test_a_file_is_updated_by_the_overrides_read_as_yaml(tmp_path) -> None:
    path = tmp_path / "c.yml"
    path.write_text("seeds: 3\nlevels: [0.5]\n")
    assert config_data(Config, path, ["levels=[1, 2.0e-1]"]) == {"seeds": 3, "levels": [1, 0.2]}
    assert config_data(Config, None, ["seeds = 7"]) == {"seeds": 7}
    (tmp_path / "empty.yml").write_text("")
    assert config_data(Config, tmp_path / "empty.yml", []) == {}


@pytest.mark.parametrize(
    ("text", "overrides", "match"),
    [
        ("seeds: 3\n", ["seeds"], r"--set expects key=value, got 'seeds'"),
        ("seeds: 3\n", ["=3"], r"--set expects key=value, got '=3'"),
        ("seeds: 3\nepisodes: 2\n", [], r"unknown config key\(s\) \['episodes'\]; known"),
        ("seeds: 3\n", ["sedes=4"], r"unknown config key\(s\) \['sedes'\]"),
        ("- seeds\n- 3\n", [], r"expected a mapping of config fields"),
    ],
)
def test_bad_input_is_named(tmp_path, text, overrides, match) -> None:
    path = tmp_path / "c.yml"
    path.write_text(text)
    with pytest.raises(InvalidConfigError, match=match):
        config_data(Config, path, overrides)


def test_every_entry_point_reads_its_config_this_way() -> None:
    pytest.importorskip("optuna", reason="the 'tune' extra")
    from train import adversary, evaluate, fronts, tune

    for module in (evaluate, tune, fronts, adversary):
        with pytest.raises(InvalidConfigError, match=r"unknown config key\(s\) \['nope'\]"):
            module.load_config(None, ["nope=1"])
    assert parse_set(["a=1.0e-3", "b=x", "c=1e-3"]) == {"a": 1e-3, "b": "x", "c": "1e-3"}
