"""Command lines generated from config dataclasses: one source of truth.

A command's configuration is one dataclass whose fields carry attribute docstrings (a
string literal right after the field). :func:`add_config_arguments` turns it into
``--config FILE`` (YAML, keys = fields), repeated ``--set field=value`` (value read as
YAML) and one flag per field (``episode_s`` → ``--episode-s``; ``bool`` → ``--x/--no-x``;
``list[T]``, ``tuple[...]`` → its values; ``X | None`` → also ``null``, and ``none`` unless X is
``str``, where "none" is an ordinary value); :func:`config_from_args` builds the instance
with the precedence defaults < file < ``--set`` < flags, checking every value against
its annotation, then calls its ``validate()``. :func:`to_argv` is the inverse.
SB3 hyperparameters are not config fields: ``ptrack train`` reads them under ``--hp``
(:mod:`train.rl.config`).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import difflib
import functools
import inspect
import itertools
import textwrap
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, Union

import yaml

from ptrack_gym.errors import InvalidConfigError

__all__ = [
    "add_config_arguments",
    "config_from_args",
    "field_docs",
    "load_config",
    "to_argv",
]

_RESERVED = ("config", "set")  # the dests of --config and --set
#: Keys a run writes into its ``config.yml`` as a record beside its settings (``rates``:
#: the gains each controller ran at, :mod:`train.evaluation.rate_record`; ``ran_at``: those
#: of an adversarial search's controllers). Read back as a ``--config``, a run's file is its
#: settings: a record key is skipped where the config has no field of that name.
RATES_KEY, RAN_AT_KEY = "rates", "ran_at"
RECORD_KEYS = frozenset({RATES_KEY, RAN_AT_KEY})
_BOOL_WORDS = {"true": True, "yes": True, "on": True, "false": False, "no": False, "off": False}


# -- fields: docstrings and types --------------------------------------------------------
@functools.cache
def _own_docs(klass: type) -> Mapping[str, str]:
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
    except (OSError, TypeError, SyntaxError):  # no source (built in a REPL, frozen, ...)
        return {}
    body = next((n.body for n in tree.body if isinstance(n, ast.ClassDef)), [])
    docs = {}
    for stmt, after in itertools.pairwise(body):
        if (
            isinstance(stmt, ast.AnnAssign)
            and isinstance(stmt.target, ast.Name)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[stmt.target.id] = inspect.cleandoc(after.value.value)
    return types.MappingProxyType(docs)


def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings of the dataclass ``cls``'s fields, inherited ones included
    (a subclass's docstring of a field wins); a field without one, or a class whose source
    cannot be read, is absent."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            docs.update(_own_docs(klass))
    return {f.name: docs[f.name] for f in _fields(cls) if f.name in docs}


def _fields(cls: type) -> list[dataclasses.Field]:
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise InvalidConfigError(f"{cls!r} is not a dataclass")
    return [f for f in dataclasses.fields(cls) if f.init]


@functools.cache
def _hints(cls: type) -> Mapping[str, Any]:
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # an annotation that does not resolve: that field is unchecked
        hints = {}
    return {f.name: hints.get(f.name, Any) for f in _fields(cls)}


def _split_optional(tp: Any) -> tuple[bool, Any]:
    """``X | None`` → (True, X); anything else → (False, tp)."""
    if typing.get_origin(tp) in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) < len(typing.get_args(tp)):
            return True, args[0] if len(args) == 1 else Union[tuple(args)]  # noqa: UP007
    return False, tp


def _item_types(base: Any) -> tuple[Any, ...] | None:
    """list[T], tuple[T, ...] → (T, ...); tuple[A, B] → (A, B); not a sequence → None."""
    origin = base if base in (list, tuple) else typing.get_origin(base)
    args = typing.get_args(base)
    if origin is list or (origin is tuple and (not args or args[-1] is ...)):
        return ((args or (Any,))[0], ...)
    return args if origin is tuple else None


def _type_name(tp: Any) -> str:
    optional, base = _split_optional(tp)
    origin, items = typing.get_origin(base) or base, _item_types(base)
    if origin is Literal:
        name = f"one of {list(typing.get_args(base))}"
    elif items is not None:
        shown = items[:1] if items[-1:] == (...,) else items
        name = f"a {origin.__name__} of {', '.join(map(_type_name, shown))}"
    else:
        name = getattr(base, "__name__", str(base))
    return f"{name} or null" if optional else name


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _flow(value: Any) -> str:
    """``value`` as one line of YAML (flow style), which :func:`yaml.safe_load` reads back."""
    return (
        yaml.safe_dump(value, default_flow_style=True, width=1 << 30)
        .removesuffix("\n...\n")
        .strip()
    )


# -- values --------------------------------------------------------------------------------
def _coerce(name: str, tp: Any, value: Any, where: str, text: bool) -> Any:
    """``value`` checked against ``tp``. A string where a number is expected is parsed as
    one (PyYAML reads ``1e-3`` as a string); with ``text`` (a flag's words) strings are
    also read as bools and ``null``/``none`` as None.

    Raises:
        InvalidConfigError: naming the field, where the value came from and the type.
    """

    def bad() -> InvalidConfigError:
        return InvalidConfigError(f"{name} ({where}): expected {_type_name(tp)}, got {value!r}")

    optional, base = _split_optional(tp)
    origin = typing.get_origin(base)
    if value is None or base is Any:
        if value is None and not optional and base is not Any:
            raise bad()
        return value
    if text and optional:  # a word "null", or "none" where a string could not be "none"
        word = value[0] if isinstance(value, list) and len(value) == 1 else value
        stringy = base is str or any(a is str or a == "none" for a in typing.get_args(base))
        if isinstance(word, str) and word.lower() in ("null", "none")[: 1 if stringy else 2]:
            return None
    items = _item_types(base)
    if items is not None:
        variadic = items[-1:] == (...,)
        if not isinstance(value, (list, tuple)) or not (variadic or len(value) == len(items)):
            raise bad()
        try:
            out = [
                _coerce(name, t, v, where, text)
                for t, v in zip([items[0]] * len(value) if variadic else items, value, strict=True)
            ]
        except InvalidConfigError:
            raise bad() from None
        return tuple(out) if (origin or base) is tuple else out
    if origin is Literal:
        for choice in typing.get_args(base):
            if (value == choice and type(value) is type(choice)) or (
                isinstance(value, str) and value == str(choice)
            ):
                return choice
        raise bad()
    if base is bool:
        if text and isinstance(value, str):
            value = _BOOL_WORDS.get(value.lower(), value)
        if isinstance(value, bool):
            return value
        raise bad()
    if base in (int, float):  # an int is a float; a bool is neither
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise bad()
        if base is int and isinstance(value, float):
            raise bad()
        try:
            return base(value)
        except (ValueError, OverflowError):
            raise bad() from None
    kind = origin or base  # dict[str, Any] → dict
    if isinstance(kind, type) and not isinstance(value, kind):
        if text and isinstance(value, str):  # dict and other types: the words are YAML
            try:
                return _coerce(name, tp, yaml.safe_load(value), where, text=False)
            except (yaml.YAMLError, InvalidConfigError):
                pass  # the message names what was typed
        raise bad()
    return value


def split_assignment(item: str, flag: str, what: str = "field") -> tuple[str, str]:
    """``(name, raw)`` of a command-line ``name=raw`` given to option ``flag`` (``--set``,
    ``--rate``), the name stripped.

    Raises:
        InvalidConfigError: no ``=`` or no name ("``flag`` expects ``what``=value").
    """
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise InvalidConfigError(f"{flag} expects {what}=value, got {item!r}")
    return key, raw


def yaml_value(raw: str, flag: str, name: str) -> Any:
    """``raw`` read as YAML (``--set name=raw``, ``--rate name=raw``).

    Raises:
        InvalidConfigError: not YAML, naming ``flag`` and ``name``.
    """
    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise InvalidConfigError(f"{flag} {name}: not YAML: {raw!r} ({exc})") from None


def _set_value(name: str, tp: Any, raw: str) -> Any:
    """The value of ``--set name=raw``: YAML, except that a str field keeps the raw text
    of a number, bool or date (``--set out=2024`` is the folder "2024")."""
    value = yaml_value(raw, "--set", name)
    base = _split_optional(tp)[1]
    if base is str and value is not None and not isinstance(value, str):
        value = raw.strip()
    return _coerce(name, tp, value, "--set", text=False)


def _unknown(keys: Iterable[str], known: Sequence[str], where: str) -> InvalidConfigError:
    keys = sorted(keys)
    close = sorted({m for k in keys for m in difflib.get_close_matches(k, known, n=3)})
    hint = f"did you mean {close}? " if close else ""
    return InvalidConfigError(f"unknown field(s) {keys} {where}; {hint}known: {sorted(known)}")


# -- the parser ----------------------------------------------------------------------------
def add_config_arguments(
    parser: argparse.ArgumentParser,
    cls: type,
    *,
    exclude: Iterable[str] = (),
    flags: Mapping[str, str | Sequence[str]] | None = None,
) -> None:
    """Add ``--config PATH``, repeated ``--set field=value`` and one flag per field of the
    dataclass ``cls`` (but ``exclude``) to ``parser``; ``flags`` maps a field to extra
    option strings (``{"env_id": "--env"}``). A flag's help is the field's docstring and
    its default. Flags store what was typed, and only when given (``argparse.SUPPRESS``):
    :func:`config_from_args` converts and checks.

    Raises:
        InvalidConfigError: ``cls`` is not a dataclass, or an unknown or reserved field.
    """
    exclude, flags = set(exclude), dict(flags or {})
    names = [f.name for f in _fields(cls)]
    if set(exclude) - set(names) or set(flags) - set(names):
        raise _unknown((exclude | set(flags)) - set(names), names, "in exclude/flags")
    docs, hints = field_docs(cls), _hints(cls)
    parser.add_argument(
        "--config", metavar="PATH", help=f"YAML file of {cls.__name__} fields (the flags win)"
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="FIELD=VALUE",
        help="set a field, the value read as YAML (repeatable; flags win)",
    )  # fmt: skip
    group = parser.add_argument_group(f"{cls.__name__} fields")
    for f in _fields(cls):
        if f.name in exclude:
            continue
        if f.name in _RESERVED:
            raise InvalidConfigError(f"field {f.name!r} clashes with --{f.name}: exclude it")
        extra = flags.get(f.name, ())
        options = [_flag(f.name), *([extra] if isinstance(extra, str) else extra)]
        default = _default(f)
        shown = "required" if default is dataclasses.MISSING else f"default: {_flow(default)}"
        kwargs: dict[str, Any] = {
            "dest": f.name,
            "default": argparse.SUPPRESS,
            "help": f"{' '.join(docs.get(f.name, '').split())} ({shown})".replace("%", "%%"),
        }
        base = _split_optional(hints[f.name])[1]
        if base is bool:  # bool | None: the flags say True/False, --set field=null says None
            kwargs["action"] = argparse.BooleanOptionalAction
        else:
            items = _item_types(base)
            if items is None:
                kwargs["metavar"] = _metavar(base)
            elif items[-1:] == (...,):
                kwargs.update(nargs="+", metavar=_metavar(items[0]))
            else:
                kwargs.update(nargs=len(items), metavar=tuple(map(_metavar, items)))
        group.add_argument(*options, **kwargs)


def _metavar(tp: Any) -> str:
    if typing.get_origin(tp) is Literal:
        return "{" + ",".join(map(str, typing.get_args(tp))) + "}"
    return _type_name(tp).upper().replace(" ", "_")


def config_from_args(
    cls: type,
    args: argparse.Namespace,
    *,
    defaults_file: Path | str | None = None,
    validate: bool = True,
) -> Any:
    """The ``cls`` instance of parsed ``args``: its defaults, updated by the YAML file
    ``args.config`` (else ``defaults_file``, if any), then ``args.set``, then every
    attribute of ``args`` named like a field (the flags given); then ``validate()`` (unless
    ``validate`` is false).

    Raises:
        InvalidConfigError: an unknown field, a value of the wrong type, a missing required
            field, or whatever ``validate()`` raises.
    """
    hints, names = _hints(cls), [f.name for f in _fields(cls)]
    data: dict[str, Any] = {}
    path = getattr(args, "config", None) or defaults_file
    if path is not None:
        try:
            loaded = yaml.safe_load(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise InvalidConfigError(f"config file {path}: {exc}") from None
        if not isinstance(loaded, dict):
            raise InvalidConfigError(f"config file {path}: expected a mapping of fields")
        loaded = {k: v for k, v in loaded.items() if k in names or k not in RECORD_KEYS}
        if set(loaded) - set(names):
            raise _unknown(set(loaded) - set(names), names, f"in {path}")
        data.update({k: _coerce(k, hints[k], v, str(path), text=False) for k, v in loaded.items()})
    for item in getattr(args, "set", None) or []:
        key, raw = split_assignment(item, "--set")
        if key not in hints:
            raise _unknown([key], names, "in --set")
        data[key] = _set_value(key, hints[key], raw)
    for name in names:
        if name not in _RESERVED and hasattr(args, name):
            data[name] = _coerce(name, hints[name], getattr(args, name), _flag(name), text=True)
    missing = [
        f.name for f in _fields(cls) if f.name not in data and _default(f) is dataclasses.MISSING
    ]
    if missing:
        raise InvalidConfigError(
            f"missing required field(s) {missing}: {', '.join(map(_flag, missing))}"
        )
    instance = cls(**data)
    if validate and callable(getattr(instance, "validate", None)):
        instance.validate()
    return instance


def load_config(
    cls: type, path: Path | str | None, overrides: Iterable[str] = (), *, validate: bool = True
) -> Any:
    """The ``cls`` instance of the YAML file ``path`` (None: the defaults) updated by
    ``--set``-style ``field=value`` overrides — what the command line builds without flags
    (:func:`config_from_args`, with its checks and, if ``validate``, ``validate()``)."""
    args = argparse.Namespace(config=path, set=list(overrides))
    return config_from_args(cls, args, validate=validate)


def to_argv(
    instance: Any, *, command: str | Sequence[str] | None = None, full: bool = False
) -> list[str]:
    """An argv that :func:`config_from_args` (of a parser made by
    :func:`add_config_arguments`) turns back into an instance equal to ``instance``: a flag
    per field that differs from its default (every field with ``full``), ``--set`` where a
    flag cannot say it (an empty list, ``"null"``, a list item starting with ``-``);
    ``command`` first."""
    cls = type(instance)
    hints = _hints(cls)
    argv = [command] if isinstance(command, str) else list(command or [])
    for f in _fields(cls):
        value, default, tp = getattr(instance, f.name), _default(f), hints[f.name]
        if not full and default is not dataclasses.MISSING and value == default:
            continue
        flag, base = _flag(f.name), _split_optional(tp)[1]
        if base is bool and isinstance(value, bool):
            argv.append(flag if value else "--no-" + flag[2:])
            continue
        words = _flag_words(f.name, tp, value)
        if words is None:
            argv += ["--set", f"{f.name}={_flow(value)}"]
        elif len(words) == 1 and words[0].startswith("-"):  # "-1e-05" would read as a flag
            argv.append(f"{flag}={words[0]}")
        else:
            argv += [flag, *words]
    return argv


def _flag_words(name: str, tp: Any, value: Any) -> list[str] | None:
    """The words after ``--name`` that read back as ``value``; None where there are none."""
    many = isinstance(value, (list, tuple))
    words = [
        repr(v) if isinstance(v, float) else v if isinstance(v, str) else _flow(v)
        for v in (value if many else [value])
    ]
    if value is None:
        words = ["null"]
    elif many and (not words or any(w.startswith("-") for w in words)):
        return None  # nargs="+" takes no empty list, and a "-x" item for a flag
    try:
        back = _coerce(name, tp, words if many else words[0], "", text=True)
    except InvalidConfigError:
        return None
    return words if back == value else None
