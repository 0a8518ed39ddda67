"""Command lines generated from config dataclasses (``train.common.arguments``): help from
the field docstrings, the precedence defaults < file < --set < flags, values checked
against the annotations, ``to_argv`` as the exact inverse"""

from __future__ import annotations

import argparse
import dataclasses
import string
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import pytest

from ptrack_gym.errors import InvalidConfigError
from train.common.arguments import (
    add_config_arguments,
    config_from_args,
    field_docs,
    to_argv,
)


@dataclass
class Sweep:
    """A small config of the shapes the real ones use."""

    out: str
    """Output folder."""
    episode_s: float = 6.0
    """Episode length (s); 100% of it is recorded."""
    seeds: int = 5
    """Seeds 0..seeds−1."""
    levels: list[float] = field(default_factory=lambda: [0.5, 1.0])
    """Levels of every preset."""
    controllers: list[str] = field(default_factory=lambda: ["passivity"])
    """Controller names."""
    path_seed: int | None = None
    """Seed of a random path."""
    eval_disturbance: str | None = None
    """Disturbance of the evaluation env ("none" is a preset); None: the training one."""
    scale: float | None = None
    """Residual acceleration scale (rad/s²)."""
    weights: list[float] | None = None
    """Reward weights; None: the env's."""
    tags: list[str] | None = None
    """Labels ("none" is one)."""
    window_s: tuple[float, float] = (0.5, 2.0)
    """Onset window (s)."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Further env arguments."""
    plots: bool = True
    """Write the PNG figures."""
    video: bool = False
    """Record one episode per controller."""
    backend: Literal["process", "ray"] = "process"
    """Where episodes run."""

    def validate(self) -> None:
        if self.seeds < 1:
            raise InvalidConfigError(f"seeds must be >= 1, got {self.seeds}")


@dataclass
class LongSweep(Sweep):
    """A subclass: inherits the fields and their docs, adds one, re-documents one."""

    seeds: int = 20
    """Seeds of the long sweep."""
    workers: int = 0
    """Episode runners (0: cores)."""


def parse(argv: list[str], cls: type = Sweep, **kwargs: Any) -> Any:
    parser = argparse.ArgumentParser(prog="ptrack test")
    add_config_arguments(parser, cls, flags=kwargs.pop("flags", None))
    return config_from_args(cls, parser.parse_args(argv), **kwargs)


def test_the_field_docstrings_and_defaults_are_the_help() -> None:
    parser = argparse.ArgumentParser(prog="ptrack test")
    add_config_arguments(parser, Sweep)
    text = " ".join(parser.format_help().split())
    assert "--episode-s FLOAT Episode length (s); 100% of it is recorded. (default: 6.0)" in text
    assert "--out STR Output folder. (required)" in text
    assert "--plots, --no-plots Write the PNG figures. (default: true)" in text
    assert "--levels FLOAT [FLOAT ...] Levels of every preset. (default: [0.5, 1.0])" in text
    assert "--backend {process,ray} Where episodes run." in text
    assert "--window-s FLOAT FLOAT Onset window (s). (default: [0.5, 2.0])" in text
    assert "--config PATH" in text and "--set FIELD=VALUE" in text


def test_a_subclass_inherits_the_field_docs() -> None:
    docs = field_docs(LongSweep)
    assert docs["out"] == "Output folder."
    assert docs["seeds"] == "Seeds of the long sweep."  # its own wins
    assert docs["workers"] == "Episode runners (0: cores)."
    assert list(docs) == [f.name for f in dataclasses.fields(LongSweep)]
    assert field_docs(Sweep)["seeds"] == "Seeds 0..seeds−1."
    assert parse(["--out", "o", "--workers", "3"], LongSweep).workers == 3


def test_a_class_without_source_has_no_docs_but_a_parser() -> None:
    made = dataclasses.make_dataclass("Made", [("seeds", int, 1)])
    assert field_docs(made) == {}
    assert parse(["--seeds", "4"], made) == made(seeds=4)


def test_precedence_defaults_file_set_flags(tmp_path) -> None:
    path = tmp_path / "c.yml"
    path.write_text("out: from_file\nseeds: 2\nepisode_s: 1\nlevels: [3]\n")
    cfg = parse(["--config", str(path), "--set", "seeds=3", "--set", "episode_s=2"])
    assert (cfg.out, cfg.seeds, cfg.episode_s, cfg.levels) == ("from_file", 3, 2.0, [3.0])
    assert isinstance(cfg.episode_s, float)  # an int given for a float
    cfg = parse(["--config", str(path), "--set", "seeds=3", "--seeds", "4", "--out", "o"])
    assert (cfg.out, cfg.seeds, cfg.video) == ("o", 4, False)
    # defaults_file stands in for --config, which replaces it
    assert parse([], defaults_file=path).seeds == 2
    other = tmp_path / "other.yml"
    other.write_text("out: other\n")
    assert parse(["--config", str(other)], defaults_file=path).seeds == 5


def test_bools_both_ways(tmp_path) -> None:
    assert parse(["--out", "o", "--no-plots", "--video"]).plots is False
    assert parse(["--out", "o", "--video"]).video is True
    assert parse(["--out", "o", "--set", "plots=false", "--plots"]).plots is True
    path = tmp_path / "c.yml"
    path.write_text("out: o\nplots: no\n")
    assert parse(["--config", str(path)]).plots is False
    with pytest.raises(InvalidConfigError, match=r"plots \(--set\): expected bool, got 1"):
        parse(["--out", "o", "--set", "plots=1"])


def test_optional_fields_take_null_and_none_where_it_is_not_a_string() -> None:
    base = ["--out", "o"]
    assert parse([*base, "--path-seed", "none"]).path_seed is None
    assert parse([*base, "--path-seed", "NULL"]).path_seed is None
    assert parse([*base, "--path-seed", "7"]).path_seed == 7
    assert parse([*base, "--set", "path_seed=7", "--set", "path_seed=null"]).path_seed is None
    assert parse([*base, "--scale", "none"]).scale is None
    assert parse([*base, "--weights", "none"]).weights is None
    assert parse([*base, "--weights", "1", "2"]).weights == [1.0, 2.0]
    assert parse([*base, "--tags", "none"]).tags == ["none"]
    assert parse([*base, "--tags", "null"]).tags is None
    assert parse([*base, "--window-s", "1", "3"]).window_s == (1.0, 3.0)
    assert parse([*base, "--set", "window_s=[0, 1.5]"]).window_s == (0.0, 1.5)
    assert parse([*base, "--env-kwargs", "{reward: kernel}"]).env_kwargs == {"reward": "kernel"}
    # for a str field "none" is a value (the disturbance preset), null is None
    assert parse([*base, "--eval-disturbance", "none"]).eval_disturbance == "none"
    assert parse([*base, "--eval-disturbance", "null"]).eval_disturbance is None
    with pytest.raises(InvalidConfigError, match=r"path_seed \(--path-seed\): expected int or"):
        parse([*base, "--path-seed", "x"])


def test_lists_and_scalars_are_checked_against_the_annotations(tmp_path) -> None:
    base = ["--out", "o"]
    assert parse([*base, "--levels", "1", "-2.5", "1e-3"]).levels == [1.0, -2.5, 1e-3]
    assert parse([*base, "--set", "levels=[1.0e-3, 2]"]).levels == [1e-3, 2.0]
    assert parse([*base, "--set", "episode_s=1e-3"]).episode_s == 1e-3  # PyYAML: a string
    assert parse(["--set", "out=2024"]).out == "2024"  # a str field keeps the text
    cases = [
        (["--set", "levels=0.5"], r"levels \(--set\): expected a list of float, got 0\.5"),
        (["--set", "controllers=x"], r"controllers \(--set\): expected a list of str, got 'x'"),
        (["--seeds", "2.5"], r"seeds \(--seeds\): expected int, got '2\.5'"),
        (["--set", "seeds=2.5"], r"seeds \(--set\): expected int, got 2\.5"),
        (["--set", "seeds=true"], r"seeds \(--set\): expected int, got True"),
        (
            ["--levels", "1", "x"],
            r"levels \(--levels\): expected a list of float, got \['1', 'x'\]",
        ),
        (["--backend", "thread"], r"backend \(--backend\): expected one of \['process', 'ray'\]"),
        (["--set", "out=null"], r"out \(--set\): expected str, got None"),
        (["--set", "window_s=[1]"], r"window_s \(--set\): expected a tuple of float, float"),
        (["--env-kwargs", "[1]"], r"env_kwargs \(--env-kwargs\): expected dict, got '\[1\]'"),
        (["--seeds", "0"], r"seeds must be >= 1, got 0"),  # validate()
    ]
    for argv, match in cases:
        with pytest.raises(InvalidConfigError, match=match):
            parse([*base, *argv])
    path = tmp_path / "c.yml"
    path.write_text("out: o\nlevels: '0.5'\n")
    with pytest.raises(InvalidConfigError, match=rf"levels \({path}\): expected a list of float"):
        parse(["--config", str(path)])
    with pytest.raises(InvalidConfigError, match=r"missing required field\(s\) \['out'\]: --out"):
        parse([])


def test_unknown_fields_are_named_with_close_matches(tmp_path) -> None:
    with pytest.raises(InvalidConfigError, match=r"\['episodes_s'\] in --set; did you mean \["):
        parse(["--out", "o", "--set", "episodes_s=1"])
    try:
        parse(["--out", "o", "--set", "episodes_s=1"])
    except InvalidConfigError as exc:
        assert "'episode_s'" in str(exc).split("known:")[0]
    path = tmp_path / "c.yml"
    path.write_text("out: o\nseed: 1\nnope: 2\n")
    with pytest.raises(
        InvalidConfigError, match=r"unknown field\(s\) \['nope', 'seed'\] in .*c\.yml.*known: \["
    ):
        parse(["--config", str(path)])
    path.write_text("- a\n")
    with pytest.raises(InvalidConfigError, match=r"expected a mapping of fields"):
        parse(["--config", str(path)])
    with pytest.raises(InvalidConfigError, match=r"--set expects field=value, got 'seeds'"):
        parse(["--out", "o", "--set", "seeds"])


def test_exclude_flags_and_reserved_names() -> None:
    parser = argparse.ArgumentParser()
    add_config_arguments(parser, Sweep, exclude=["video"], flags={"seeds": ["-s", "--n-seeds"]})
    args = parser.parse_args(["--out", "o", "-s", "2"])
    assert config_from_args(Sweep, args).seeds == 2
    with pytest.raises(SystemExit):
        parser.parse_args(["--video"])
    with pytest.raises(InvalidConfigError, match=r"\['vidoe'\] in exclude/flags; did you mean"):
        add_config_arguments(argparse.ArgumentParser(), Sweep, exclude=["vidoe"])
    clash = dataclasses.make_dataclass("Clash", [("config", str, "x")])
    with pytest.raises(InvalidConfigError, match=r"'config' clashes with --config"):
        add_config_arguments(argparse.ArgumentParser(), clash)
    add_config_arguments(argparse.ArgumentParser(), clash, exclude=["config"])


def test_to_argv_says_only_what_differs_unless_full() -> None:
    cfg = Sweep(out="o", seeds=3, plots=False, levels=[], path_seed=-4)
    argv = to_argv(cfg, command="evaluate")
    assert argv == ["evaluate", "--out", "o", "--seeds", "3", "--set", "levels=[]",
                    "--path-seed=-4", "--no-plots"]  # fmt: skip
    assert parse(argv[1:]) == cfg
    full = to_argv(cfg, full=True)
    assert "--episode-s" in full and "--backend" in full and "--no-video" in full
    assert parse(full) == cfg


def _random_sweep(rng: np.random.Generator) -> Sweep:
    words = ["none", "null", "", "-x", "a b", "1.5", "true", "a=b", "~", "[1]", "x: y", "--no"]

    def text() -> str:
        if rng.random() < 0.5:
            return str(rng.choice(words))
        return "".join(rng.choice(list(string.printable[:-5]), size=rng.integers(1, 8)))

    def number() -> float:
        return float(
            rng.choice([0.0, -1e-5, 1e300, -2.5, float(rng.normal() * 10.0 ** rng.integers(-8, 8))])
        )

    return Sweep(
        out=text(),
        episode_s=number(),
        seeds=int(rng.integers(1, 10**6)),
        levels=[number() for _ in range(rng.integers(0, 4))],
        controllers=[text() for _ in range(rng.integers(0, 4))],
        path_seed=None if rng.random() < 0.3 else int(rng.integers(-(10**6), 10**6)),
        eval_disturbance=None if rng.random() < 0.3 else text(),
        scale=None if rng.random() < 0.3 else number(),
        weights=None if rng.random() < 0.3 else [number() for _ in range(rng.integers(0, 3))],
        tags=None if rng.random() < 0.3 else [text() for _ in range(rng.integers(0, 3))],
        window_s=(number(), number()),
        plots=bool(rng.random() < 0.5),
        video=bool(rng.random() < 0.5),
        backend=str(rng.choice(["process", "ray"])),  # type: ignore[arg-type]
    )


def test_to_argv_round_trips() -> None:
    hand_picked = [
        Sweep(out="o"),
        Sweep(out="-o", controllers=["-x", "y"], eval_disturbance="null", scale=-0.0),
        Sweep(out="", levels=[-1e-5], controllers=[], eval_disturbance="none", seeds=1),
        Sweep(out="x: y", episode_s=float("inf"), path_seed=-3, backend="ray", video=True),
        Sweep(out="o", weights=[], tags=["null"], scale=1e-300),
        Sweep(out="o", weights=[1.0], tags=["none", "-"], eval_disturbance="~"),
        Sweep(out="o", env_kwargs={"reward": "kernel", "w": [-1.0, 2], "x": None}),
    ]
    rng = np.random.default_rng(0)
    for cfg in hand_picked + [_random_sweep(rng) for _ in range(300)]:
        for full in (False, True):
            argv = to_argv(cfg, full=full)
            assert parse(argv) == cfg, argv
    long = LongSweep(out="o", workers=2, seeds=7)
    assert parse(to_argv(long), LongSweep) == long


@dataclass
class Normalize:
    """A tri-state switch: on, off, or the hyperparameter file's choice."""

    vec_normalize: bool | None = None
    """Wrap the envs in VecNormalize; None: the file's choice."""


def test_an_optional_bool_is_a_switch_and_null_is_none() -> None:
    assert parse([], Normalize).vec_normalize is None
    assert parse(["--vec-normalize"], Normalize).vec_normalize is True
    assert parse(["--no-vec-normalize"], Normalize).vec_normalize is False
    assert parse(["--vec-normalize", "--set", "vec_normalize=null"], Normalize).vec_normalize
    assert parse(["--set", "vec_normalize=null"], Normalize).vec_normalize is None
    for value in (None, True, False):
        config = Normalize(value)
        assert parse(to_argv(config), Normalize) == config
