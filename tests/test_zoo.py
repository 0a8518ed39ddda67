"""Residual ids in Gymnasium's registry (registered by ``import agents``), and training
through the real rl-baselines3-zoo client on a plain and a residual id with the
project's hyperparameter YAML."""

from __future__ import annotations

import ast
import itertools
import re
import shlex
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import agents
from agents.policy import ControllerPolicy
from agents.registry import CONTROLLER_NAMES, make_controller
from agents.residual import make_residual_env, residual_env_id
from ptrack_gym import ENV_IDS

ROOT = Path(__file__).resolve().parents[1]

#: The env arguments of docs/rl.md's rl-zoo3 example: 5-s episodes at 250 Hz.
ZOO_ENV_KWARGS = ["control_hz:250.0", "max_episode_steps:1250", "horizon_s:5.0"]


def _zoo_kwargs(words: list[str]) -> dict:
    """rl-zoo3's ``--env-kwargs key:value`` words as the keyword arguments of ``gym.make``
    (rl-zoo3 evaluates each value; literals here)."""
    return {k: ast.literal_eval(v) for k, _, v in (w.partition(":") for w in words)}


def test_every_robot_and_base_has_a_residual_id() -> None:
    expected = {residual_env_id(e, b) for e in ENV_IDS for b in CONTROLLER_NAMES}
    assert set(agents.RESIDUAL_ENV_IDS) == expected
    assert "ptrack_gym/IiwaTrack-Residual-ComputedTorque-v0" in gym.registry
    assert "ptrack_gym/TwoLinkTrack-Residual-SlotineLi-v0" in gym.registry
    for env_id in expected:
        spec = gym.spec(env_id)
        assert isinstance(spec.entry_point, str)  # nothing is imported until gym.make
        assert (
            spec.max_episode_steps
            == gym.spec(env_id.split("-Residual-")[0] + "-v0").max_episode_steps
        )


def test_import_ptrack_gym_imports_nothing_of_agents() -> None:
    code = "import sys, gymnasium, ptrack_gym; assert 'agents' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_a_residual_id_after_import_ptrack_gym_alone_works_or_says_import_agents() -> None:
    """``gym.make`` of a residual id with only ``ptrack_gym`` imported either builds it
    (importing ``agents`` then, through the string entry point) or raises an error that
    says ``import agents`` — never a bare ``NameNotFound``; the residual ids ``ptrack_gym``
    registers, if any, are those of ``agents``' bases."""
    code = (
        "import sys, gymnasium, ptrack_gym\n"
        "assert 'agents' not in sys.modules\n"
        "try:\n"
        "    env = gymnasium.make('ptrack_gym/TwoLinkTrack-Residual-Passivity-v0',"
        " control_hz=250.0, max_episode_steps=10)\n"
        "except Exception as exc:\n"
        "    assert 'import agents' in str(exc), repr(exc)\n"
        "else:\n"
        "    assert type(env.unwrapped).__name__ == 'TrackingEnv'\n"
        "    assert env.spec.entry_point == 'agents.residual_ids:residual_env'\n"
        "mine = {i for i in gymnasium.registry if '-Residual-' in i}\n"
        "import agents\n"  # every base of agents' registry, no other: the lists agree
        "theirs = set(agents.RESIDUAL_ENV_IDS)\n"
        "assert not mine or mine == theirs, mine ^ theirs\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_registered_id_is_the_residual_wrapper_bit_for_bit() -> None:
    kw = {"control_hz": 250.0, "disturbance": "impulse", "action_penalty": 0.05}
    reg = gym.make("ptrack_gym/TwoLinkTrack-Residual-Passivity-v0", max_episode_steps=200, **kw)
    ref = make_residual_env("ptrack_gym/TwoLinkTrack-v0", "passivity", max_episode_steps=200, **kw)
    rng = np.random.default_rng(0)
    o1, _ = reg.reset(seed=3)
    o2, _ = ref.reset(seed=3)
    np.testing.assert_array_equal(o1, o2)
    for _ in range(200):
        a = rng.uniform(-1, 1, 2)
        s1, s2 = reg.step(a), ref.step(a)
        np.testing.assert_array_equal(s1[0], s2[0])
        assert s1[1:4] == s2[1:4]
    again = gym.make(reg.spec)  # the spec re-creates it: one wrapper, same arguments
    assert type(again.unwrapped).__name__ == "TrackingEnv"
    assert again.spec.kwargs == reg.spec.kwargs and not again.spec.additional_wrappers
    for e in (reg, ref, again):
        e.close()


def test_zero_action_on_a_registered_id_is_the_base_controller() -> None:
    env = gym.make("ptrack_gym/TwoLinkTrack-Residual-ComputedTorque-v0", control_hz=250.0)
    plain = gym.make("ptrack_gym/TwoLinkTrack-v0", control_hz=250.0)
    policy = ControllerPolicy(plain, make_controller("computed_torque", plain))
    obs, _ = env.reset(seed=1)
    o, _ = plain.reset(seed=1)
    for _ in range(100):
        obs, r, *_ = env.step(np.zeros(2))
        o, r0, *_ = plain.step(policy.predict(o)[0])
        np.testing.assert_array_equal(obs[: o.shape[0]], o)
        assert r == r0
    env.close()
    plain.close()


def test_bad_arguments_of_a_registered_id_raise() -> None:
    with pytest.raises(TypeError):
        gym.make("ptrack_gym/TwoLinkTrack-Residual-Passivity-v0", no_such_argument=1)
    with pytest.raises(ValueError):
        gym.make("ptrack_gym/TwoLinkTrack-Residual-Passivity-v0", gate_rad=-1.0)


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo", "ppo_lstm"])
def test_yaml_sections_are_complete_for_the_zoo(algo: str) -> None:
    """rl-zoo3 reads only an env's section when there is one; our loader merges it over
    ``default``. The sections' YAML merge (``<<: *default``) makes the two agree."""
    pytest.importorskip("stable_baselines3")
    from train.rl.hyperparameters import load_hyperparams

    data = yaml.safe_load((ROOT / "train" / "hyperparams" / f"{algo}.yml").read_text())
    for env_id, section in data.items():
        if env_id != "default":
            assert load_hyperparams(algo, env_id, None, {}) == section


def test_the_documented_zoo_example_runs_the_intended_episodes() -> None:
    """docs/rl.md's rl-zoo3 command sets the control rate with the episode length: 1 250
    steps at 250 Hz, 5 s — not the id's 10 000 steps (10 s at 1 kHz), 40 s at 250 Hz —, and
    the disturbances' horizon to match; an episode of the example truncates at 5 s."""
    docs = (ROOT / "docs" / "rl.md").read_text()
    block = re.search(r"```bash\n(python -m rl_zoo3\.train.*?)```", docs, re.S)
    assert block, "docs/rl.md has no rl_zoo3.train example"
    words = shlex.split(block.group(1).replace("\\\n", " "))
    start = words.index("--env-kwargs") + 1
    given = list(itertools.takewhile(lambda w: not w.startswith("--"), words[start:]))
    assert given == ZOO_ENV_KWARGS
    kwargs = _zoo_kwargs(given)
    for env_id in (words[words.index("--env") + 1], "ptrack_gym/TwoLinkTrack-v0"):
        env = gym.make(env_id, **kwargs)
        config = env.unwrapped.config
        assert env.spec.max_episode_steps / config.control_hz == 5.0 == config.horizon_s
        env.reset(seed=0)
        steps, truncated = 0, False
        while not truncated:
            _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
            assert not terminated
            steps += 1
        assert steps / config.control_hz == 5.0
        env.close()


@pytest.mark.parametrize(
    "env_id",
    [  # the residual id goes through everything the plain one does (make test-slow runs both)
        pytest.param("ptrack_gym/TwoLinkTrack-v0", marks=pytest.mark.slow),
        "ptrack_gym/TwoLinkTrack-Residual-Passivity-v0",
    ],
)
def test_rl_zoo3_trains_a_plain_and_a_residual_id(tmp_path: Path, env_id: str) -> None:
    pytest.importorskip("rl_zoo3", reason="the optional 'zoo' extra is not installed")
    cmd = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "sac", "--env", env_id,
        "--gym-packages", "agents", "--conf-file", "train/hyperparams/sac.yml",
        "-n", "300", "--hyperparams", "learning_starts:100", "buffer_size:1000",
        "batch_size:32", "policy_kwargs:dict(net_arch=[32])",
        "--env-kwargs", *ZOO_ENV_KWARGS, "-f", str(tmp_path), "--eval-freq", "-1",
        "--seed", "0", "--vec-env", "dummy",
    ]  # fmt: skip
    env = {"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    saved = list(tmp_path.glob(f"sac/{env_id.replace('/', '-')}_1/*.zip"))
    assert saved, done.stdout[-2000:]
    from stable_baselines3 import SAC

    model = SAC.load(str(saved[0]), device="cpu")
    assert model.num_timesteps == 300
