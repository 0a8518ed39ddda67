"""The joint dampers' share of the passivity law's phase-loop budget, and what the rule that
caps it changes (loop 7 of docs/control_rates.md): every robot's default and tuned gains,
built with the rule (``DAMPER_SHARE_MAX`` = 0.9) and without it, on the default path and
random admissible paths, at several control rates.

    python bench/damper_share.py                       # the survey of loop 7 (~10 min)
    python bench/damper_share.py --robots iiwa --hz 250 --paths 307

The share is max_s q_r'ᵀD q_r' / (0.8 · 2 M_r(s)/dt) of the gains built with the rule.
Prints one line per build — robot, path (``default`` or the seed), rate, gain set, whether
it was refused without the rule and with it, whether the two gain sets are equal, the
share — then per robot the builds, the refusals each way, the builds the rule changed and
the largest share among those it left alone.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents import passivity_gains
from agents.base import ControlContext
from agents.passivity import PassivityController
from agents.passivity_gains import damper_share
from agents.passivity_tables import passivity_tables
from agents.registry import entry, tuned_rates
from ptrack_gym.errors import ControlRateError
from ptrack_gym.robots import ROBOTS, robot_profile

#: The rule's cap as the package sets it.
DEFAULT_CAP = passivity_gains.DAMPER_SHARE_MAX
#: The survey of loop 7: the default path (None) and random paths 1-40, 201-220, 301-310.
SURVEY_PATHS: tuple[int | None, ...] = (
    None, *range(1, 41), *range(201, 221), *range(301, 311)
)  # fmt: skip


def build(ctx: ControlContext, rates: dict | None, cap: float) -> PassivityController | None:
    """The passivity controller of ``rates`` (None: the defaults) with the dampers' share
    capped at ``cap`` (``inf``: the rule off), or None where it is refused."""
    passivity_gains.DAMPER_SHARE_MAX = cap
    try:
        return entry("passivity").build(ctx, rates)
    except ControlRateError:
        return None
    finally:
        passivity_gains.DAMPER_SHARE_MAX = DEFAULT_CAP


def survey(
    robots: Sequence[str], rates_hz: Sequence[float], paths: Sequence[int | None]
) -> list[dict]:
    """One row per (robot, path, rate, gain set), printed as it is built."""
    rows = []
    for robot in robots:
        for seed in paths:
            kw = {"path": "default"} if seed is None else {"path": "random", "path_seed": seed}
            env = gym.make(robot_profile(robot).env_id, **kw)
            ctx0 = ControlContext.from_env(env)
            tables = passivity_tables(ctx0.path, ctx0.model)
            for hz in rates_hz:
                ctx = dataclasses.replace(ctx0, dt_s=1.0 / hz)
                for gain_set in ("default", "tuned"):
                    rates = None if gain_set == "default" else tuned_rates(robot, "passivity")
                    off, on = build(ctx, rates, np.inf), build(ctx, rates, DEFAULT_CAP)
                    share = np.nan if on is None else damper_share(tables, on.d_diag, 1.0 / hz)
                    row = {
                        "robot": robot, "path": "default" if seed is None else seed,
                        "hz": hz, "gains": gain_set, "refused_before": off is None,
                        "refused_now": on is None,
                        "same": off is not None and on is not None and off.gains == on.gains,
                        "share": share,
                    }  # fmt: skip
                    rows.append(row)
                    print(*list(row.values())[:-1], f"{row['share']:.3f}", flush=True)
            env.close()
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument("--hz", nargs="+", type=float, default=[1000.0, 500.0, 250.0, 100.0])
    parser.add_argument(
        "--paths", nargs="+", type=int, default=None,
        help="random path seeds (default: the survey's, with the default path)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    paths = SURVEY_PATHS if args.paths is None else tuple(args.paths)
    rows = survey(args.robots, args.hz, paths)
    print("\nrobot  builds  refused before  refused now  changed  largest share left alone")
    for robot in args.robots:
        mine = [r for r in rows if r["robot"] == robot]
        alone = [r["share"] for r in mine if r["same"]]
        print(
            robot, len(mine), sum(r["refused_before"] for r in mine),
            sum(r["refused_now"] for r in mine), sum(not r["same"] for r in mine),
            f"{max(alone):.3f}" if alone else "-",
        )  # fmt: skip


if __name__ == "__main__":
    main()
