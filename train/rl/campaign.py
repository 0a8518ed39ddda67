"""Train every run of a multi-seed RL study: (group × seed) ``train.rl.run`` runs, one
process each, ``--workers`` at a time, resumable.

The study is a YAML file (``train/configs/rl_study_*.yml``)::

    seeds: [0, 1, 2, 3, 4]
    common:                     # TrainConfig fields of every run (train.rl.run.TrainConfig)
      env_id: ptrack_gym/TwoLinkTrack-v0
      steps: 60000              # the sample budget of every run (equal budgets)
      overrides: {policy_kwargs: "dict(net_arch=[64, 64])"}
    groups:                     # per group, fields over ``common`` (overrides merged key by key)
      pure: {residual: none}
      residual-passivity: {residual: passivity, zero_init_residual: true}

Run ``<out>/<group>_s<seed>`` gets seed ``seed``. A run whose final checkpoint holds the
budget is skipped; an interrupted one (a checkpoint short of the budget) is continued with
``--resume`` for the remaining steps; any other is started. A run that fails is reported
at the end and does not stop the others; the exit status is then 1.

Usage::

    ptrack campaign --config train/configs/campaign/rl_study_two_link.yml \\
        --out runs/rl_study_two_link --workers 2

``--groups`` and ``--seeds`` train a part of the file (the same run folders: a campaign
split across sessions or machines, each part resumable on its own).

``--backend ray`` (the ``ray`` extra) runs them as one-CPU Ray tasks instead — on a local
instance of ``--workers`` CPUs, or on the cluster at ``--ray-address`` — with the same
skipping and resuming (the same models: tested). Then ``ptrack study --runs <out> ...``
evaluates the checkpoints.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import traceback
from collections.abc import Iterator, Sequence
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import yaml

from ptrack_gym.errors import InvalidConfigError
from train.common.signals import sigterm_as_interrupt
from train.rl.checkpoints import latest_checkpoint
from train.rl.config import TrainConfig, validate
from train.rl.hyperparameters import TrainConfigError

_CONFIG_KEYS = {"seeds", "common", "groups"}


def load_campaign(
    path: Path,
    out: Path,
    groups: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
) -> list[TrainConfig]:
    """The study's runs as validated-in-form :class:`TrainConfig` s (fresh, no resume);
    with ``groups`` or ``seeds``, only those of the file's (a campaign split across
    sessions or machines: the runs and their folders are those of the whole campaign).

    Raises:
        TrainConfigError: unknown top-level keys, an unknown TrainConfig field, no seeds
            or groups, a selected group or seed the file does not have.
    """
    raw = yaml.safe_load(path.read_text()) or {}
    if not isinstance(raw, dict):
        raise TrainConfigError(f"{path}: expected a mapping")
    unknown = set(raw) - _CONFIG_KEYS
    if unknown:
        raise TrainConfigError(f"{path}: unknown keys {sorted(unknown)}; known: {_CONFIG_KEYS}")
    all_seeds = [int(x) for x in raw.get("seeds") or []]
    all_groups = raw.get("groups") or {}
    if not all_seeds or not all_groups:
        raise TrainConfigError(f"{path}: needs 'seeds' and 'groups'")
    for kind, chosen, known_ones in (("group", groups, list(all_groups)),
                                     ("seed", seeds, all_seeds)):  # fmt: skip
        missing = [x for x in chosen or [] if x not in known_ones]
        if missing:
            raise TrainConfigError(f"{path}: no {kind} {missing}; it has {known_ones}")
    seeds = [x for x in all_seeds if seeds is None or x in seeds]
    group_specs = {g: v for g, v in all_groups.items() if groups is None or g in groups}
    common = dict(raw.get("common") or {})
    known = {f.name for f in fields(TrainConfig)} - {"out", "seed", "resume"}
    runs = []
    for group, spec in group_specs.items():
        merged = {**common, **(spec or {})}
        merged["overrides"] = {
            **(common.get("overrides") or {}),
            **((spec or {}).get("overrides") or {}),
        }
        bad = set(merged) - known
        if bad:
            raise TrainConfigError(f"{path}: group {group}: unknown fields {sorted(bad)}")
        for seed in seeds:
            runs.append(
                TrainConfig(out=str(out / f"{group}_s{int(seed)}"), seed=int(seed), **merged)
            )
    return runs


def validate_campaign(path: Path) -> int:
    """Validate every run of the study ``path`` (no file or env touched); the run count.

    Raises:
        TrainConfigError: the first bad run config.
    """
    runs = load_campaign(path, Path("/nonexistent"))
    for cfg in runs:
        validate(cfg)
    return len(runs)


def plan(cfg: TrainConfig) -> TrainConfig | None:
    """What to do for one run: None if its budget is trained, else the config to run
    (``resume=True`` with the remaining steps when it was interrupted)."""
    run_dir = Path(cfg.out)
    budget = validate(replace(cfg, out="/nonexistent")).steps
    found = latest_checkpoint(run_dir)
    if found is None:
        if (run_dir / "config.yml").exists():  # started, no checkpoint yet: start over
            (run_dir / "config.yml").unlink()
        return replace(cfg, steps=budget)
    done = found[0]
    if done >= budget:
        return None
    return replace(cfg, steps=budget - done, resume=True)


def _train_one(cfg: TrainConfig) -> tuple[str, str | None]:
    """Train one run; its ``command.txt`` records the standalone ``ptrack train``
    command of this invocation (:func:`train.rl.config.to_argv`)."""
    from train.rl.config import to_argv
    from train.rl.run import run

    if cfg.progress_bar is None:  # the workers share one terminal: no bars unless asked
        cfg = replace(cfg, progress_bar=False)
    try:
        with sigterm_as_interrupt():  # Pool.terminate's SIGTERM: the run saves where it got to
            run(cfg, argv=to_argv(cfg))
    except Exception:  # reported, never silently dropped
        return cfg.out, traceback.format_exc()
    return cfg.out, None


def _results(
    todo: Sequence[TrainConfig], workers: int, backend: str, address: str | None, ctx: Any
) -> Iterator[tuple[str, str | None]]:
    """(run folder, error or None) of every run, as each finishes: in a pool of ``workers``
    spawned processes (one run each), or as one-CPU Ray tasks (a cluster at ``address``,
    else a local instance of ``workers`` CPUs)."""
    if backend == "ray":
        from train.common.ray_tasks import ray_results

        for _, result in ray_results(_train_one, [(c,) for c in todo], workers, address):
            yield result
        return
    with ctx.Pool(max(1, workers), maxtasksperchild=1) as pool:
        yield from pool.imap_unordered(_train_one, todo)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="ptrack campaign", description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--out", type=Path, help="the runs' folder (default: runs/<config name>)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument(
        "--backend", choices=("process", "ray"), default="process",
        help="a pool of --workers processes, or Ray tasks (the 'ray' extra; one CPU each)",
    )  # fmt: skip
    p.add_argument("--ray-address", help="with --backend ray: a running cluster's address")
    p.add_argument("--groups", nargs="+", metavar="GROUP",
                   help="train only these groups of the file (default: every group)")  # fmt: skip
    p.add_argument("--seeds", nargs="+", type=int, metavar="SEED",
                   help="train only these seeds of the file (default: every seed)")  # fmt: skip
    args = p.parse_args(argv)
    if args.workers < 1:
        p.error(f"--workers must be >= 1, got {args.workers}")
    if args.backend == "ray":
        from train.evaluation.config import require_extra

        try:
            require_extra("ray", "ray", "--backend ray")
        except InvalidConfigError as exc:
            p.error(str(exc))
    if args.out is None:
        args.out = Path("runs") / args.config.stem
    validate_campaign(args.config)  # every run checked before the first starts
    try:
        runs = load_campaign(args.config, args.out, args.groups, args.seeds)
    except TrainConfigError as exc:
        p.error(str(exc))
    todo: list[Any] = [c for c in map(plan, runs) if c]
    print(f"{len(todo)} runs to train into {args.out}", flush=True)
    failed = []
    ctx = mp.get_context("spawn")
    # SIGTERM (kill, a scheduler) is an interruption like Ctrl-C: leaving the ``with`` block
    # terminates the pool, each worker's run saves where it got to, and the pool joins them
    # before this process exits; without it the parent dies alone and its spawned workers
    # train on, orphaned.
    interrupted = False
    try:
        with sigterm_as_interrupt():
            for out, error in _results(todo, args.workers, args.backend, args.ray_address, ctx):
                print(f"{'FAILED' if error else 'done'}: {out}", flush=True)
                if error:
                    failed.append((out, error))
    except KeyboardInterrupt:
        interrupted = True
    for out, error in failed:
        print(f"--- {out}\n{error}")
    if interrupted:
        print("interrupted: the running runs saved their steps; the same command resumes them",
              flush=True)  # fmt: skip
        return 130
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
