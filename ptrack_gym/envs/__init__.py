"""Gymnasium environments of ptrack_gym."""

from ptrack_gym.envs.tracking import TrackingEnv

__all__ = ["TrackingEnv"]
