"""Reading a run's config: a YAML file of a config dataclass's fields, updated by the
``key=value`` overrides every entry point takes as ``--set`` (values read as YAML, so
``1.0e-3`` is a float and ``[a, b]`` a list; PyYAML reads ``1e-3``, without the point, as
a string). Light on purpose: no torch, no SB3."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from ptrack_gym.errors import InvalidConfigError


def parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``["key=value", ...]`` → dict; values are read as YAML (``1.0e-3`` → float).

    Raises:
        InvalidConfigError: an item without ``=`` or with an empty key.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InvalidConfigError(f"--set expects key=value, got {item!r}")
        out[key.strip()] = yaml.safe_load(value)
    return out


def config_data(cls: type, path: Path | None, overrides: Sequence[str]) -> dict[str, Any]:
    """The fields of the config dataclass ``cls``: those of the YAML file ``path`` (None: no
    file; an empty file: none), updated by ``overrides`` (:func:`parse_set`).

    Raises:
        InvalidConfigError: the file is not a mapping, an override is malformed, or a key
            is not a field of ``cls`` (the message lists the known ones).
    """
    data: dict[str, Any] = {}
    if path is not None:
        data = yaml.safe_load(path.read_text()) or {}
        if not isinstance(data, dict):
            raise InvalidConfigError(f"{path}: expected a mapping of config fields")
    data.update(parse_set(overrides))
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InvalidConfigError(f"unknown config key(s) {unknown}; known: {sorted(known)}")
    return data
