"""Residual reinforcement learning on top of a model-based controller: the public names.

The residual env is four modules, each one job:

* :mod:`agents.residual_spec` — :class:`ResidualSpec`, every option of a residual policy
  in one frozen record, and the checks of each option;
* :mod:`agents.residual_features` — the base controller's block of the observation;
* :mod:`agents.residual_wrapper` — :class:`ResidualWrapper`, τ = τ_base + the learned
  correction (the equations, safeguards and info), and :func:`make_residual_env`;
* :mod:`agents.residual_ids` — the registered ids ``ptrack_gym/<Robot>Track-Residual-<Base>-v0``.

This module re-exports their public names.
"""

from agents.registry import PRIOR_BASES
from agents.residual_features import (
    PRIOR_ERROR_FEATURES,
    ControllerFeatures,
    prior_error_names,
)
from agents.residual_ids import register_residual_envs, residual_env, residual_env_id
from agents.residual_spec import (
    DEFAULT_SCALE_FRACTION,
    NETWORK_BASE,
    RESIDUAL_BASES,
    RUN_OPTIONS,
    SPEC_FIELDS,
    WRAPPER_DEFAULTS,
    ResidualSpec,
    check_base_gains,
    check_base_model,
    check_prior,
    check_safeguards,
    resolve_spec,
    split_options,
)
from agents.residual_wrapper import ResidualWrapper, build_base, make_residual_env, wrap

__all__ = [
    "DEFAULT_SCALE_FRACTION",
    "NETWORK_BASE",
    "PRIOR_BASES",
    "PRIOR_ERROR_FEATURES",
    "RESIDUAL_BASES",
    "RUN_OPTIONS",
    "SPEC_FIELDS",
    "WRAPPER_DEFAULTS",
    "ControllerFeatures",
    "ResidualSpec",
    "ResidualWrapper",
    "build_base",
    "check_base_gains",
    "check_base_model",
    "check_prior",
    "check_safeguards",
    "make_residual_env",
    "prior_error_names",
    "register_residual_envs",
    "residual_env",
    "residual_env_id",
    "resolve_spec",
    "split_options",
    "wrap",
]
