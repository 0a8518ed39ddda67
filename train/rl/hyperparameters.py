"""Hyperparameters in rl-baselines3-zoo's format: YAML files, safe literal parsing,
validation against the algorithm's constructor.

A file ``train/hyperparams/<algo>.yml`` has a ``default:`` section and optional
``<env id>:`` sections; values are constructor arguments of the SB3 algorithm, plus the
zoo's special keys (``n_timesteps``, ``normalize``, ``n_envs``, ``noise_type``,
``noise_std``). ``policy_kwargs`` and ``normalize`` may be Python-literal strings, parsed by
:func:`parse_python_literal` without executing code.
"""

from __future__ import annotations

import ast
import inspect
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.utils import LinearSchedule
from torch import nn

from ptrack_gym.errors import InvalidConfigError
from train.evaluation.policies import algo_class

#: The packaged hyperparameter files, ``<algo>.yml``.
HYPERPARAMS_DIR = Path(__file__).resolve().parents[1] / "hyperparams"
#: Keys of a hyperparameter YAML that are not arguments of the algorithm's constructor.
SPECIAL_KEYS = ("n_timesteps", "normalize", "n_envs", "noise_type", "noise_std")
#: Constructor arguments the training script sets itself.
_RESERVED = ("self", "env", "tensorboard_log", "verbose", "seed", "device", "_init_setup_model")
#: Names a ``policy_kwargs`` / ``normalize`` string may use (besides dict/list literals).
SAFE_NAMES: dict[str, Any] = {
    "nn.ReLU": nn.ReLU,
    "nn.Tanh": nn.Tanh,
    "nn.ELU": nn.ELU,
    "nn.LeakyReLU": nn.LeakyReLU,
    "nn.GELU": nn.GELU,
    "nn.SiLU": nn.SiLU,
    "True": True,
    "False": False,
    "None": None,
}


class TrainConfigError(InvalidConfigError):
    """A training configuration is invalid (raised before anything is trained or written)."""


def parse_python_literal(text: str) -> Any:
    """Evaluate a ``policy_kwargs``-style string safely, e.g.
    ``"dict(net_arch=[256, 256], activation_fn=nn.ReLU)"``.

    Allowed: numbers, strings, lists, tuples, ``{...}`` dicts, ``dict(key=value, ...)``,
    unary minus, and the names of :data:`SAFE_NAMES`. Anything else raises
    :class:`TrainConfigError`; no code is executed.
    """
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise TrainConfigError(f"cannot parse {text!r}: {exc.msg}") from None

    def convert(node: ast.AST) -> Any:
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, (ast.List, ast.Tuple)):
            items = [convert(e) for e in node.elts]
            return items if isinstance(node, ast.List) else tuple(items)
        if isinstance(node, ast.Dict):
            if any(k is None for k in node.keys):
                raise TrainConfigError(f"'**' is not allowed in {text!r}")
            return {convert(k): convert(v) for k, v in zip(node.keys, node.values, strict=True)}
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            value = convert(node.operand)
            if not isinstance(value, (int, float)):
                raise TrainConfigError(f"unary sign on a non-number in {text!r}")
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.Call):
            if not (isinstance(node.func, ast.Name) and node.func.id == "dict") or node.args:
                raise TrainConfigError(f"only dict(key=value, ...) calls are allowed in {text!r}")
            if any(kw.arg is None for kw in node.keywords):
                raise TrainConfigError(f"'**' is not allowed in {text!r}")
            return {kw.arg: convert(kw.value) for kw in node.keywords}
        name = ast.unparse(node)
        if isinstance(node, (ast.Name, ast.Attribute)) and name in SAFE_NAMES:
            return SAFE_NAMES[name]
        raise TrainConfigError(
            f"{name!r} is not allowed in {text!r}; allowed names: {sorted(SAFE_NAMES)}"
        )

    return convert(tree.body)


def parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``["key=value", ...]`` (``--hp``) → dict; values are read as YAML (``1.0e-3`` → float;
    PyYAML reads ``1e-3``, without the point, as a string), ``policy_kwargs`` and
    ``normalize`` literals stay strings for :func:`parse_python_literal`.

    Raises:
        TrainConfigError: an item without ``=`` or with an empty key.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise TrainConfigError(f"--hp expects key=value, got {item!r}")
        out[key.strip()] = yaml.safe_load(value)
    return out


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise TrainConfigError(f"hyperparameter file not found: {path}") from None
    if data is None:
        return {}
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise TrainConfigError(f"{path}: expected a mapping of sections (default, env ids)")
    return data


def load_hyperparams(
    algo: str, env_id: str, extra_file: str | None, overrides: dict[str, Any]
) -> dict[str, Any]:
    """The merged hyperparameters of a run (unvalidated, strings not yet parsed).

    Precedence, lowest first: ``<algo>.yml``'s ``default``, its ``<env_id>`` section,
    then the same two sections of ``extra_file``, then ``overrides``.
    """
    merged: dict[str, Any] = {}
    files = [HYPERPARAMS_DIR / f"{algo}.yml"]
    if extra_file is not None:
        files.append(Path(extra_file))
    for path in files:
        data = _read_yaml(path)
        merged.update(data.get("default", {}))
        merged.update(data.get(env_id, {}))
    merged.update(overrides)
    return merged


def _allowed_keys(algo_cls: type[BaseAlgorithm]) -> set[str]:
    params = set(inspect.signature(algo_cls.__init__).parameters) - set(_RESERVED)
    return params | set(SPECIAL_KEYS)


def resolve_hyperparams(
    algo: str, raw: dict[str, Any], backend: str = "sb3"
) -> tuple[dict[str, Any], dict]:
    """Validate and convert hyperparameters.

    Returns ``(algo_kwargs, special)``: the constructor arguments (``policy_kwargs`` and
    ``normalize`` strings parsed by :func:`parse_python_literal`, ``lin_<x>`` learning
    rates turned into linear schedules from x to 0, lists for ``train_freq`` into
    tuples, ``noise_type``/``noise_std`` into ``action_noise``) and the special keys.

    The keys are checked against the constructor of ``algo`` in ``backend``
    (:func:`train.evaluation.policies.algo_class`): sbx's classes take nearly SB3's arguments.

    Raises:
        TrainConfigError: an unknown key (the message lists the known ones) or a value
            that cannot be converted.
    """
    try:
        algo_cls = algo_class(algo, backend)
    except InvalidConfigError as exc:
        raise TrainConfigError(str(exc)) from None
    allowed = _allowed_keys(algo_cls)
    unknown = sorted(set(raw) - allowed)
    if unknown:
        raise TrainConfigError(
            f"unknown hyperparameter(s) {unknown} for {algo}; known: {sorted(allowed)}"
        )
    kwargs = {k: v for k, v in raw.items() if k not in SPECIAL_KEYS}
    special = {k: raw[k] for k in SPECIAL_KEYS if k in raw}
    kwargs.setdefault("policy", "MlpPolicy")
    if isinstance(kwargs.get("policy_kwargs"), str):
        kwargs["policy_kwargs"] = parse_python_literal(kwargs["policy_kwargs"])
    if kwargs.get("policy_kwargs") is not None and not isinstance(kwargs["policy_kwargs"], dict):
        raise TrainConfigError(f"policy_kwargs must be a dict, got {kwargs['policy_kwargs']!r}")
    for key in ("learning_rate", "clip_range"):
        value = kwargs.get(key)
        if isinstance(value, str):
            if not value.startswith("lin_"):
                raise TrainConfigError(f"{key}: a number or 'lin_<start>', got {value!r}")
            try:
                kwargs[key] = LinearSchedule(float(value[4:]), 0.0, 1.0)
            except ValueError:
                raise TrainConfigError(f"{key}: bad linear schedule {value!r}") from None
    if isinstance(kwargs.get("train_freq"), list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    if "noise_type" in special:
        if algo == "ppo":
            raise TrainConfigError("noise_type / noise_std apply to sac and td3 only")
        special.setdefault("noise_std", 0.1)
    if isinstance(special.get("normalize"), str):
        special["normalize"] = parse_python_literal(special["normalize"])
    normalize = special.get("normalize", False)
    if not isinstance(normalize, (bool, dict)):
        raise TrainConfigError(f"normalize must be a bool or a dict, got {normalize!r}")
    if isinstance(normalize, dict):
        known = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon"}
        bad = sorted(set(normalize) - known)
        if bad:
            raise TrainConfigError(f"unknown VecNormalize option(s) {bad}; known: {sorted(known)}")
    return kwargs, special


def action_noise(special: dict[str, Any], n_actions: int) -> Any:
    if "noise_type" not in special:
        return None
    std = float(special["noise_std"]) * np.ones(n_actions)
    kind = special["noise_type"]
    if kind == "normal":
        return NormalActionNoise(np.zeros(n_actions), std)
    if kind == "ornstein-uhlenbeck":
        return OrnsteinUhlenbeckActionNoise(np.zeros(n_actions), std)
    raise TrainConfigError(f"noise_type must be 'normal' or 'ornstein-uhlenbeck', got {kind!r}")
