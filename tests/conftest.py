"""Shared pytest fixtures: environment factories that always close what they made, and a
path seed made to have no admissible random path."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

import ptrack_gym  # noqa: F401  (registers the environment ids)


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_pytests_tmp(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """A model trained without a logger of its own (``model.learn`` in a test) writes SB3's
    default log folder under pytest's temporary directory, not a new ``/tmp/SB3-<date>``
    per model (they were left behind by every run of the suite)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))
    yield
    mp.undo()


class EnvFactory:
    """Makes environments with ``gym.make`` and remembers them, so a fixture can close them.

    ``track`` registers an environment made some other way (a pickled copy, a bare
    ``TrackingEnv``) for the same clean-up.
    """

    def __init__(self) -> None:
        self._envs: list[gym.Env[Any, Any]] = []

    def __call__(self, env_id: str, **kwargs: Any) -> gym.Env[Any, Any]:
        """``gym.make(env_id, **kwargs)``, closed at the end of the test."""
        return self.track(gym.make(env_id, **kwargs))

    def track(self, env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
        """Close ``env`` at the end of the test; returns it unchanged."""
        self._envs.append(env)
        return env

    def close_all(self) -> None:
        """Close every tracked environment (closing twice is part of the contract)."""
        for env in self._envs:
            env.close()
        self._envs.clear()


@pytest.fixture
def make_env() -> Iterator[EnvFactory]:
    """A :class:`EnvFactory` whose environments are closed after the test."""
    factory = EnvFactory()
    yield factory
    factory.close_all()


@pytest.fixture
def no_admissible_path(monkeypatch: pytest.MonkeyPatch) -> Callable[[int], None]:
    """``no_admissible_path(seed)``: from then on, the random path of ``seed`` (any robot)
    has no admissible draw — ``random_multisine`` raises as it does after its last try."""
    import numpy as np

    import ptrack_gym.paths as paths

    real = paths.random_multisine
    refused: set[int] = set()

    def picky(profile, rng, *args, **kw):  # type: ignore[no-untyped-def]
        for seed in refused:
            if rng.bit_generator.state == np.random.default_rng(seed).bit_generator.state:
                raise paths.InvalidPathError(
                    f"no admissible random path for {profile.name} in 200 draws"
                )
        return real(profile, rng, *args, **kw)

    monkeypatch.setattr(paths, "random_multisine", picky)
    return refused.add


@pytest.fixture
def without_panda_gains(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``agents/tuned`` without the Panda's files, for tests that ask for tuned gains on a
    robot that has none (the shipped files cover every robot once its fight has run)."""
    import shutil

    import agents.registry as registry

    tuned = tmp_path / "tuned_without_panda"
    tuned.mkdir()
    for f in registry.TUNED_DIR.glob("*.yml"):
        if not f.name.startswith("panda-"):
            shutil.copy(f, tuned / f.name)
    monkeypatch.setattr(registry, "TUNED_DIR", tuned)
