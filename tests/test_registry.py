"""The controller registry: one entry per controller, and every other table a read-only
view of that one."""

from __future__ import annotations

import gymnasium as gym
import pytest

from agents import passivity, registry
from agents.base import Controller
from agents.registry import (
    CONTROLLER_NAMES,
    CONTROLLERS,
    ENTRIES,
    PRIOR_BASES,
    RATE_MODULES,
    TUNABLE,
    ControllerEntry,
    effective_rates,
    entry,
    make_controller,
    scaled_rates,
)
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import robot_profile

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"


def test_every_view_is_derived_from_the_one_table() -> None:
    entries = list(ENTRIES.values())
    assert all(isinstance(e, ControllerEntry) for e in entries)
    assert CONTROLLER_NAMES == tuple(e.name for e in entries) == tuple(ENTRIES)
    assert dict(CONTROLLERS) == {e.name: e.build for e in entries}
    assert dict(RATE_MODULES) == {e.name: e.rates for e in entries}
    assert dict(TUNABLE) == {e.name: e.rates.TUNABLE for e in entries if e.tunable}
    assert PRIOR_BASES == tuple(e.name for e in entries if e.prior_base)


def test_views_are_read_only() -> None:
    for view in (ENTRIES, CONTROLLERS, RATE_MODULES, TUNABLE):
        with pytest.raises(TypeError):
            view["lqr"] = None  # type: ignore[index]


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_each_rate_source_states_consistent_rates(name: str) -> None:
    """Bandwidths and tunable rates are rates the controller has; ranges are ordered."""
    source = entry(name).rates
    assert isinstance(source.NAME, str)
    assert set(source.BANDWIDTHS) <= set(source.DEFAULT_RATES)
    assert set(source.TUNABLE) <= set(source.DEFAULT_RATES)
    for low, high, log in source.TUNABLE.values():
        assert 0 < low < high and isinstance(log, bool)


def test_unknown_names_raise_the_package_error_listing_the_known_ones() -> None:
    profile = robot_profile("two_link")
    for call in (
        lambda: entry("lqr"),
        lambda: effective_rates(profile, "lqr"),
        lambda: scaled_rates(profile, "lqr", "default", 2.0),
    ):
        with pytest.raises(InvalidConfigError, match="unknown controller 'lqr'; known"):
            call()
    with pytest.raises(InvalidConfigError, match="gains must be one of"):
        effective_rates(profile, "pd_gravity", "stiff")


def test_scaled_rates_multiply_only_the_bandwidths() -> None:
    profile = robot_profile("two_link")
    base = effective_rates(profile, "passivity")
    scaled = scaled_rates(profile, "passivity", "default", 2.0)
    for rate, value in base.items():
        factor = 2.0 if rate in entry("passivity").rates.BANDWIDTHS else 1.0
        assert scaled[rate] == (value * factor if factor != 1.0 else value)


def test_an_entry_added_to_the_table_is_a_controller_everywhere(make_env, monkeypatch) -> None:
    """Adding a controller is one entry: make_controller finds it by name."""
    pd = entry("pd_gravity")
    table = {**ENTRIES, "pd_twin": ControllerEntry("pd_twin", pd.build, pd.rates)}
    monkeypatch.setattr(registry, "ENTRIES", table)
    env = make_env(TWO_LINK)
    twin = make_controller("pd_twin", env)
    assert isinstance(twin, Controller)
    assert twin.gains == make_controller("pd_gravity", env).gains


@pytest.mark.parametrize("name", sorted(TUNABLE))
def test_every_corner_of_a_tuning_box_builds_the_controller(name: str) -> None:
    """The tuner may hand a controller any point of its box: the lowest and the highest
    corner both build (a rate the law fixes — the paper's law's damping ratio — would be
    refused here)."""
    env = gym.make(TWO_LINK)
    try:
        for side in (0, 1):
            rates = {rate: box[side] for rate, box in TUNABLE[name].items()}
            ctrl = make_controller(name, env, rates)
            assert ctrl is not None
    finally:
        env.close()


def test_the_paper_law_tunes_no_rate_it_fixes() -> None:
    assert "damping_ratio" in TUNABLE["passivity"]
    assert not set(TUNABLE["passivity_paper"]) & set(passivity.PAPER_LAW)
    assert set(TUNABLE["passivity_paper"]) == set(TUNABLE["passivity"]) - set(passivity.PAPER_LAW)


def test_the_paper_laws_rates_are_the_ones_it_runs() -> None:
    """``effective_rates`` applies the rates the paper's law fixes, whatever the robot's
    profile says (the iiwa's re-synchronises σ; the paper's law does not)."""
    profile = robot_profile("iiwa")
    assert effective_rates(profile, "passivity")["sync_rate"] > 0.0
    rates = effective_rates(profile, "passivity_paper")
    assert {k: rates[k] for k in passivity.PAPER_LAW} == passivity.PAPER_LAW


@pytest.mark.parametrize("robot", ["two_link", "xarm6"])
@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_the_pinned_default_rates_build_the_default_controller(name: str, robot: str) -> None:
    """What a residual run or a search records (:func:`pinned_rates`: every numeric rate,
    of the default or of the tuned gains) builds exactly the default (tuned) controller, and
    the tuned pin holds the tuned file's rates."""
    from agents.registry import pinned_rates, tuned_rates

    profile = robot_profile(robot)
    env = gym.make(profile.env_id)
    try:
        pinned = pinned_rates(profile, name, "default")
        assert pinned and all(isinstance(v, (int, float)) for v in pinned.values())
        built, default = make_controller(name, env, pinned), make_controller(name, env)
        assert _gains(built) == _gains(default) is not None
        tuned = pinned_rates(profile, name, "tuned")
        assert tuned.items() >= tuned_rates(robot, name).items()
        built, shipped = make_controller(name, env, tuned), make_controller(name, env, "tuned")
        assert _gains(built) == _gains(shipped)
    finally:
        env.close()


def _gains(controller: Controller) -> object:
    """A controller's absolute gains (a path-following wrapper's: its inner law's and its
    own synchronisation rate)."""
    inner = getattr(controller, "inner", None)
    if inner is not None:
        return (inner.gains, controller.window_s, controller.sync_rate_1_s)
    return controller.gains


@pytest.mark.parametrize(
    ("name", "rates", "match"),
    [
        ("passivity", {}, "non-empty mapping"),
        ("passivity", [("omega", 1.0)], "non-empty mapping"),
        ("passivity", {"warp": 1.0}, "unknown rate"),
        ("passivity", {"omega": float("nan")}, "kind"),
        ("passivity", {"damping_ratio": -0.5}, "kind"),
        ("passivity", {"omega": 10**400}, "kind"),  # an int beyond any float
        ("passivity", {"omega": "fast"}, "kind"),
        ("passivity", {"omega": True}, "kind"),
        ("passivity", {"saturation_aware": 1}, "kind"),
        ("passivity_paper", {"damping_ratio": 0.5}, "fixes"),  # recorded, never run
    ],
)
def test_rates_a_controller_cannot_run_are_refused(name, rates, match) -> None:
    with pytest.raises(InvalidConfigError, match=match):
        registry.check_rates(robot_profile("two_link"), name, rates)


def test_rates_a_controller_can_run_pass_as_given() -> None:
    profile = robot_profile("two_link")
    given = {"omega": 30, "damping_ratio": 0.0, "saturation_aware": False, "pump": "paper"}
    assert registry.check_rates(profile, "passivity", given) == given
    assert registry.check_rates(profile, "passivity_paper", {"damping_ratio": 0.0, "lam": 3.0})
