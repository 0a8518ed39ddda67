"""Onsets respect the episode: a disturbance whose latest onset + duration + the recovery
window (``RECOVERY_S``) does not fit in the horizon is refused at construction, naming what
to change; where today's 1-4 s onsets fit, the drawn schedules are bit-identical to those
drawn before the check existed."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the envs)
from ptrack_gym.disturbances import (
    RECOVERY_S,
    DisturbanceContext,
    DisturbanceRunner,
    build_disturbances,
    from_spec,
    min_horizon_s,
)
from ptrack_gym.envs.config import EnvConfig
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import robot_profile

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
IIWA = "ptrack_gym/IiwaTrack-v0"

#: Every family with a timed event: (spec, the field, its latest time + duration in s).
TIMED = [
    ({"type": "impulse", "onset_s": (1.0, 4.0), "duration_s": 0.05}, "onset_s", 4.05),
    ({"type": "push", "onset_s": (1.0, 4.0), "duration_s": 0.1}, "onset_s", 4.1),
    ({"type": "step", "onset_s": (1.0, 4.0)}, "onset_s", 4.0),
    ({"type": "payload", "pick_s": (1.0, 4.0)}, "pick_s", 4.0),
    ({"type": "payload", "pick_s": 0.5, "drop_s": (2.0, 3.0)}, "drop_s", 3.0),
    ({"type": "impulse", "onset_s": 2.0, "duration_s": 0.05}, "onset_s", 2.05),
]


@pytest.mark.parametrize(("spec", "field", "end_s"), TIMED)
def test_a_horizon_too_short_for_the_latest_event_is_refused(spec, field, end_s) -> None:
    short = end_s + RECOVERY_S - 0.01
    with pytest.raises(InvalidConfigError) as info:
        EnvConfig(robot="two_link", disturbance=spec, horizon_s=short)
    text = str(info.value)
    assert text.startswith(f"{spec['type']}: {field} ")
    assert f"horizon_s = {short:g} s" in text
    assert f"recovery window {RECOVERY_S:g} s" in text and "duration" in text
    assert f"an episode of at least {end_s + RECOVERY_S:.6g} s" in text
    # exactly long enough: accepted
    EnvConfig(robot="two_link", disturbance=spec, horizon_s=end_s + RECOVERY_S)


def test_the_message_names_the_onset_range_the_duration_and_an_onset_range_that_fits() -> None:
    spec = {"type": "push", "onset_s": (1.0, 4.0), "duration_s": 0.1}
    with pytest.raises(InvalidConfigError) as info:
        EnvConfig(robot="two_link", disturbance=spec, horizon_s=2.0)
    assert str(info.value) == (
        "push: onset_s 1-4 s + duration 0.1 s + recovery window 0.5 s does not fit in the "
        "episode's horizon_s = 2 s (the disturbance could come too late to be measured, or "
        "never); use an episode of at least 4.6 s (episode_s / horizon_s), or an explicit "
        "onset_s range that ends by 1.4 s"
    )
    # the suggested range is accepted
    EnvConfig(robot="two_link", disturbance={**spec, "onset_s": (1.0, 1.4)}, horizon_s=2.0)


def test_the_issue_case_is_refused_when_the_env_is_built() -> None:
    """episode_s = 0.9 (issue 36): impulse, push and payload all came after the end."""
    for preset in ("impulse", "push", "payload", "mixed"):
        with pytest.raises(InvalidConfigError, match=r"horizon_s = 0\.9 s"):
            gym.make(TWO_LINK, disturbance=preset, horizon_s=0.9, max_episode_steps=900)
    for preset in ("none", "periodic", "noise", "mismatch"):  # no onset: any length
        gym.make(TWO_LINK, disturbance=preset, horizon_s=0.9, max_episode_steps=900).close()


def test_an_evaluation_sweep_too_short_for_its_presets_is_refused() -> None:
    from train.evaluation.config import load_config

    with pytest.raises(InvalidConfigError, match=r"impulse: onset_s 1-4 s .* horizon_s = 2 s"):
        load_config(None, ["disturbances=[none, impulse]", "episode_s=2.0", "out=unused"])
    load_config(None, ["disturbances=[none, impulse]", "episode_s=5.0", "out=unused"])


@pytest.mark.parametrize(
    ("preset", "minimum_s"),
    [("impulse", 4.55), ("push", 4.6), ("payload", 4.5), ("mixed", 4.55), ("periodic", 0.0)],
)
def test_the_shortest_episode_of_each_preset(preset, minimum_s) -> None:
    """Level 1 (the onsets do not scale with the level): the latest onset (4 s) + the
    duration (impulse 0.05 s, push 0.1 s) + RECOVERY_S; the 5-s episodes of the shipped RL
    configs fit every one."""
    for level in (0.5, 1.0, 2.0):
        items = build_disturbances((preset, level), robot_profile("iiwa"))
        assert min_horizon_s(items) == pytest.approx(minimum_s)
    if minimum_s:
        EnvConfig(robot="iiwa", disturbance=preset, horizon_s=minimum_s)
        with pytest.raises(InvalidConfigError):
            EnvConfig(robot="iiwa", disturbance=preset, horizon_s=minimum_s - 1e-3)
    EnvConfig(robot="iiwa", disturbance=preset, horizon_s=5.0)


def test_the_runner_checks_the_horizon_of_its_context() -> None:
    """A runner used without an env (``validate``) refuses the same."""
    ctx = DisturbanceContext(
        n=2, torque_limits_nm=np.ones(2), physics_dt_s=1e-3, control_dt_s=1e-3,
        horizon_s=1.0, ee_link="link2", home_mass_matrix=np.eye(2),
        ee_jacobian_home=np.zeros((3, 2)), mean_path_speed_rad_s=1.0,
    )  # fmt: skip
    runner = DisturbanceRunner([from_spec({"type": "impulse"})], 2)
    with pytest.raises(InvalidConfigError, match=r"horizon_s = 1 s"):
        runner.validate(ctx)


# Recorded from the code before onsets were checked (commit 0c90388), by
# env.reset(seed=...) and env.disturbance_schedule(): the onset (the first draw of each
# family's stream, compared bit for bit) and the torque or force it drew (sized from the
# draw by matrix arithmetic, compared to 1e-13). The check draws nothing: these stay.
OLD_ONSETS = {0: 3.8359495870428884, 7: 2.7694224722418808, 10001: 1.2158422332463328}
OLD_SCHEDULES = {
    (TWO_LINK, 5.0, "impulse", 7): [-10.868984627502659, -0.9809082545551291],
    (TWO_LINK, 5.0, "push", 10001): [4.1019716268466775, 9.108812718575319, -0.4509541334385819],
    (IIWA, 8.0, "impulse", 0): [
        12.397470213473012, 32.45827795161555, 5.963463802035688, -19.2648825838692,
        0.39763841055085875, 0.6271648930989757, -0.032216127695176115,
    ],
    (IIWA, 8.0, "push", 7): [-9.073912739077057, 12.176637697173742, 37.005318563625174],
}  # fmt: skip
OLD_MIXED_PICKS = {0: 1.5796863680435558, 7: 3.131924273258855, 10001: 1.1336492227709625}


@pytest.mark.parametrize(("env_id", "horizon_s"), [(TWO_LINK, 5.0), (IIWA, 8.0)])
def test_schedules_where_the_window_fits_are_those_drawn_before(env_id, horizon_s) -> None:
    for preset in ("impulse", "push", "payload", "mixed"):
        env = gym.make(env_id, disturbance=preset, horizon_s=horizon_s).unwrapped
        try:
            for seed, onset in OLD_ONSETS.items():
                env.reset(seed=seed)
                first = env.disturbance_schedule()[0]
                assert first.get("onset_s", first.get("pick_s")) == onset  # bit for bit
                drawn = first.get("tau_nm", first.get("force_n"))
                old = OLD_SCHEDULES.get((env_id, horizon_s, preset, seed))
                if old is not None:  # the same draw, sized by the same arithmetic: equal
                    # up to the last bits numpy's SIMD kernels leave to the CPU (an AVX-512
                    # machine differs from the recording one by 1 ulp); another draw would
                    # differ by O(1)
                    np.testing.assert_allclose(drawn, old, rtol=1e-13, atol=0.0)
                if preset == "mixed":
                    assert env.disturbance_schedule()[-1]["pick_s"] == OLD_MIXED_PICKS[seed]
        finally:
            env.close()
