"""The residual's options as one record (:class:`agents.residual_spec.ResidualSpec`): the
keyword style and the spec build the same env bit for bit, unknown options are named, and
the compatibility views are derived from the spec."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import agents.residual as residual
from agents.registry import make_controller
from agents.residual_spec import (
    RUN_OPTIONS,
    SPEC_FIELDS,
    WRAPPER_DEFAULTS,
    ResidualSpec,
    resolve_spec,
    split_options,
)
from agents.residual_wrapper import ResidualWrapper, make_residual_env
from ptrack_gym.errors import InvalidConfigError

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
SHORT = {"control_hz": 250.0, "max_episode_steps": 30, "disturbance": "impulse"}


def rollout(env, seed: int = 0) -> list:
    rng = np.random.default_rng(seed)
    out = [env.reset(seed=seed)[0]]
    for _ in range(30):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-1.2, 1.2, env.n))
        out.append((obs, reward, info["tau_base_nm"], info["tau_residual_nm"]))
        if terminated or truncated:
            break
    return out


def assert_same(a: list, b: list) -> None:
    assert len(a) == len(b)
    np.testing.assert_array_equal(a[0], b[0])
    for x, y in zip(a[1:], b[1:], strict=True):
        for u, v in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize(
    "options",
    [
        {"base": "passivity"},
        {"base": "computed_torque", "prior_gain_per_rad": 500.0, "action_penalty": 0.1},
        {"base": "slotine_li", "gate_rad": 0.01, "gate_deadband_rad": 0.001},
        {"base": "pd_gravity", "scale_accel_rad_s2": 20.0, "base_gains": "tuned"},
        {"base": "passivity_paper", "scale_fraction": 0.2, "include_controller_state": False},
    ],
)
def test_a_spec_and_its_keywords_build_the_same_env_bit_for_bit(make_env, options) -> None:
    spec = ResidualSpec(**options)
    by_spec = make_env.track(make_residual_env(TWO_LINK, spec, **SHORT))
    keywords = {k: v for k, v in options.items() if k != "base"}
    by_keywords = make_env.track(make_residual_env(TWO_LINK, options["base"], **keywords, **SHORT))
    again = make_env.track(by_spec.spec.make())
    assert by_spec.residual_spec == by_keywords.residual_spec == spec
    assert again.residual_spec == spec
    assert_same(rollout(by_spec), rollout(by_keywords))
    assert_same(rollout(by_spec), rollout(again))


def test_the_wrapper_takes_a_spec_a_name_or_an_object(make_env) -> None:
    inner = make_env(TWO_LINK, **SHORT)
    spec = ResidualSpec(base="pd_gravity", gate_rad=0.02)
    by_spec = ResidualWrapper(inner, spec=spec)
    by_name = ResidualWrapper(make_env(TWO_LINK, **SHORT), "pd_gravity", gate_rad=0.02)
    assert by_spec.residual_spec == by_name.residual_spec == spec
    assert type(by_spec.controller).__name__ == "PDGravityController"
    ctrl = make_controller("slotine_li", inner)
    by_object = ResidualWrapper(make_env(TWO_LINK, **SHORT), ctrl, spec)
    assert by_object.controller is ctrl and by_object.spec is None
    with pytest.raises(InvalidConfigError, match="given twice"):
        ResidualWrapper(make_env(TWO_LINK, **SHORT), "pd_gravity", base="slotine_li")
    with pytest.raises(InvalidConfigError, match="base_gains is for a base given by name"):
        ResidualWrapper(make_env(TWO_LINK, **SHORT), ctrl, base_gains="tuned")


def test_unknown_options_are_refused_by_name(make_env) -> None:
    with pytest.raises(InvalidConfigError, match=r"unknown residual option\(s\) \['gate', 'x'\]"):
        ResidualSpec.from_options({"gate": 0.1, "x": 1, "gate_rad": 0.1})
    with pytest.raises(InvalidConfigError, match="'gate'"):
        ResidualWrapper(make_env(TWO_LINK, **SHORT), "passivity", gate=0.1)
    with pytest.raises(TypeError, match="no_such_argument"):  # not a spec field: the env's
        make_residual_env(TWO_LINK, "passivity", no_such_argument=1)


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"base": "lqr"}, "unknown base controller"),
        ({"scale_fraction": -0.1}, "scale_fraction"),
        ({"scale_nm": 1.0, "scale_accel_rad_s2": 5.0}, "not both"),
        ({"scale_nm": [[1.0]]}, "scale_nm"),
        ({"scale_nm": -1.0}, "scale_nm"),
        ({"scale_nm": "big"}, "scale_nm"),
        ({"include_controller_state": 1}, "include_controller_state"),
        ({"base": "network"}, "needs base_model"),
        ({"base_model": "models/x"}, "base_model is for a 'network' base"),
        ({"base": "network", "base_model": "m", "base_gains": "tuned"}, "no gains"),
        ({"base": "network", "prior_gain_per_rad": 1.0, "base_model": "m"}, "control prior"),
        ({"base_gains": None}, "base_gains must be one of"),
        ({"gate_deadband_rad": 0.01}, "needs gate_rad"),
    ],
)
def test_bad_options_raise_the_package_error_naming_them(options, match: str) -> None:
    with pytest.raises(InvalidConfigError, match=match):
        ResidualSpec(**options)


def test_a_spec_is_frozen_hashable_and_normalises_the_torque_authority() -> None:
    spec = ResidualSpec(scale_nm=np.array([1.0, 2.0]))
    assert spec.scale_nm == (1.0, 2.0) and isinstance(spec.scale_nm, tuple)
    assert ResidualSpec(scale_nm=np.float64(3.0)).scale_nm == 3.0
    assert hash(spec) == hash(ResidualSpec(scale_nm=(1.0, 2.0)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.gate_rad = 0.1  # type: ignore[misc]
    assert spec.options() == {name: getattr(spec, name) for name in SPEC_FIELDS}


def test_options_split_between_the_spec_and_the_env() -> None:
    own, env = split_options({"gate_rad": 0.1, "control_hz": 250.0, "base_gains": "tuned"})
    assert own == {"gate_rad": 0.1, "base_gains": "tuned"} and env == {"control_hz": 250.0}
    spec, env = resolve_spec("slotine_li", {"gate_rad": 0.1, "control_hz": 250.0})
    assert spec == ResidualSpec(base="slotine_li", gate_rad=0.1) and env == {"control_hz": 250.0}
    start = ResidualSpec(base="pd_gravity", action_penalty=0.2)
    spec, _ = resolve_spec(start, {"gate_rad": 0.1})
    assert spec == dataclasses.replace(start, gate_rad=0.1)
    with pytest.raises(InvalidConfigError, match="given twice"):
        resolve_spec("slotine_li", {"base": "pd_gravity"})


def test_wrapper_defaults_are_the_specs_defaults_of_the_run_options() -> None:
    """The compatibility view ``train`` reads: the keys and defaults its run configs had."""
    assert dict(WRAPPER_DEFAULTS) == {
        "action_penalty": 0.0,
        "gate_rad": None,
        "gate_deadband_rad": 0.0,
        "scale_accel_rad_s2": None,
        "base_gains": "default",
        "prior_gain_per_rad": 0.0,
        "base_model": None,
        "tank": False,
        "tank_beta": 0.5,
    }
    assert tuple(WRAPPER_DEFAULTS) == RUN_OPTIONS
    assert set(RUN_OPTIONS) <= set(SPEC_FIELDS)
    assert {} != WRAPPER_DEFAULTS and dict(WRAPPER_DEFAULTS) == WRAPPER_DEFAULTS


def test_the_old_module_keeps_every_public_name() -> None:
    """``agents.residual`` re-exports what ``train`` and the tests import from it."""
    for name in (
        "DEFAULT_SCALE_FRACTION", "NETWORK_BASE", "PRIOR_BASES", "PRIOR_ERROR_FEATURES",
        "RESIDUAL_BASES", "WRAPPER_DEFAULTS", "ControllerFeatures", "ResidualWrapper",
        "check_base_gains", "check_base_model", "check_prior", "check_safeguards",
        "make_residual_env", "prior_error_names", "register_residual_envs", "residual_env",
        "residual_env_id",
    ):  # fmt: skip
        assert hasattr(residual, name), name
