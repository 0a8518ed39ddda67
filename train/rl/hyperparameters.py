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
from ptrack_gym.robots import plain_env_id
from train.common.algorithms import ON_POLICY, RECURRENT_ALGOS
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
    then the same two sections of ``extra_file``, then ``overrides``. A preview id (the
    preview observation) without a section of its own takes its plain ``-v0`` id's: the same
    robot and task.
    """
    merged: dict[str, Any] = {}
    plain = plain_env_id(env_id)
    files = [HYPERPARAMS_DIR / f"{algo}.yml"]
    if extra_file is not None:
        files.append(Path(extra_file))
    for path in files:
        data = _read_yaml(path)
        merged.update(data.get("default", {}))
        merged.update(data.get(env_id, data.get(plain, {})))
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
    kwargs.setdefault("policy", "MlpLstmPolicy" if algo in RECURRENT_ALGOS else "MlpPolicy")
    if isinstance(kwargs.get("policy_kwargs"), str):
        kwargs["policy_kwargs"] = parse_python_literal(kwargs["policy_kwargs"])
    if kwargs.get("policy_kwargs") is not None and not isinstance(kwargs["policy_kwargs"], dict):
        raise TrainConfigError(f"policy_kwargs must be a dict, got {kwargs['policy_kwargs']!r}")
    for key in ("learning_rate", "clip_range"):
        value = kwargs.get(key)
        if isinstance(value, str):
            if not value.startswith("lin_"):
                raise TrainConfigError(f"{key}: a number or 'lin_<start>', got {value!r}")
            if not _float_above_zero(value[4:]) or not np.isfinite(float(value[4:])):
                raise TrainConfigError(f"{key}: bad linear schedule {value!r} (start > 0)")
            kwargs[key] = LinearSchedule(float(value[4:]), 0.0, 1.0)
    if isinstance(kwargs.get("train_freq"), list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    if "noise_type" in special:
        if algo in ON_POLICY:
            raise TrainConfigError("noise_type / noise_std apply to sac and td3 only")
        if special["noise_type"] not in NOISE_TYPES:
            raise TrainConfigError(
                f"noise_type must be one of {list(NOISE_TYPES)}, got {special['noise_type']!r}"
            )
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
    check_domains({**kwargs, **special})
    return kwargs, special


def _integer(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _real(v: Any) -> bool:
    return isinstance(v, (int, float, np.number)) and not isinstance(v, bool) and np.isfinite(v)


def _train_freq(v: Any) -> bool:
    if isinstance(v, tuple) and len(v) == 2:
        return _integer(v[0]) and v[0] >= 1 and v[1] in ("step", "episode")
    return _integer(v) and v >= 1


def _ent_coef(v: Any) -> bool:
    if isinstance(v, str):
        head, _, tail = v.partition("_")
        return head == "auto" and (not tail or _float_above_zero(tail))
    return _real(v) and v >= 0


def _float_above_zero(text: str) -> bool:
    try:
        return float(text) > 0
    except ValueError:
        return False


#: The domain of each numeric hyperparameter (a value that is not a number fails too): a
#: value outside it would fail in SB3 — or train nonsense — only after the run folder is
#: written. A schedule (``lin_<x>``, already a callable here) is checked where it is parsed.
DOMAINS: dict[str, tuple[Any, str]] = {
    "learning_rate": (lambda v: _real(v) and v > 0, "a number > 0 or 'lin_<start>'"),
    "buffer_size": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "learning_starts": (lambda v: _integer(v) and v >= 0, "an integer >= 0"),
    "batch_size": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "tau": (lambda v: _real(v) and 0 < v <= 1, "a number in (0, 1]"),
    "gamma": (lambda v: _real(v) and 0 <= v <= 1, "a number in [0, 1]"),
    "train_freq": (_train_freq, "an integer >= 1 or [n, 'step' | 'episode']"),
    "gradient_steps": (lambda v: _integer(v) and (v >= 1 or v == -1), "an integer >= 1, or -1"),
    "n_steps": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "n_epochs": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "gae_lambda": (lambda v: _real(v) and 0 <= v <= 1, "a number in [0, 1]"),
    "clip_range": (lambda v: _real(v) and v > 0, "a number > 0 or 'lin_<start>'"),
    "clip_range_vf": (lambda v: v is None or (_real(v) and v > 0), "null or a number > 0"),
    "ent_coef": (_ent_coef, "a number >= 0, 'auto' or 'auto_<initial value > 0>'"),
    "vf_coef": (lambda v: _real(v) and v >= 0, "a number >= 0"),
    "max_grad_norm": (lambda v: _real(v) and v > 0, "a number > 0"),
    "target_update_interval": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "policy_delay": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "target_policy_noise": (lambda v: _real(v) and v >= 0, "a number >= 0"),
    "target_noise_clip": (lambda v: _real(v) and v >= 0, "a number >= 0"),
    "n_timesteps": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "n_envs": (lambda v: _integer(v) and v >= 1, "an integer >= 1"),
    "noise_std": (lambda v: _real(v) and v >= 0, "a number >= 0"),
}

#: ``noise_type`` values (rl-zoo3's names).
NOISE_TYPES = ("normal", "ornstein-uhlenbeck")


def check_domains(hyperparams: dict[str, Any]) -> None:
    """Check every numeric hyperparameter of :data:`DOMAINS` in ``hyperparams``.

    Raises:
        TrainConfigError: naming every value out of its domain at once.
    """
    bad = [
        f"{key}={value!r} (must be {what})"
        for key, (ok, what) in DOMAINS.items()
        if key in hyperparams and not callable(value := hyperparams[key]) and not ok(value)
    ]
    if bad:
        raise TrainConfigError(f"bad hyperparameter value(s): {'; '.join(bad)}")


def action_noise(special: dict[str, Any], n_actions: int) -> Any:
    if "noise_type" not in special:
        return None
    std = float(special["noise_std"]) * np.ones(n_actions)
    kind = special["noise_type"]
    if kind == "normal":
        return NormalActionNoise(np.zeros(n_actions), std)
    if kind == "ornstein-uhlenbeck":
        return OrnsteinUhlenbeckActionNoise(np.zeros(n_actions), std)
    raise TrainConfigError(f"noise_type must be one of {list(NOISE_TYPES)}, got {kind!r}")


def hyperparameter_default(algo: str, backend: str, key: str) -> Any:
    """The default of constructor argument ``key`` of ``algo`` in ``backend`` (None if the
    constructor has no such argument)."""
    params = inspect.signature(algo_class(algo, backend).__init__).parameters
    return params[key].default if key in params else None
