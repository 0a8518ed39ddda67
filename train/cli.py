"""``ptrack``: the command line of ptrack_gym, one sub-command per job.

Every job that has a config dataclass takes ``--config FILE`` (YAML, keys = its fields),
repeated ``--set field=value`` and one flag per field, generated from the dataclass
(:mod:`train.common.arguments`: ``ptrack <command> --help`` lists the fields with their
docstrings). SB3 hyperparameters of ``ptrack train`` come apart, under ``--hp key=value``.

=================  =====================================================================
``evaluate``       paired evaluation sweep (:class:`train.evaluation.config.EvalConfig`)
``train``          one RL run (:class:`train.rl.config.TrainConfig`)
``campaign``       many RL runs from one campaign file (:mod:`train.rl.campaign`)
``study``          learning curves and final tables of RL runs (:mod:`train.rl.study`)
``tune``           equal-budget gain tuning (:class:`train.studies.tune.TuneConfig`)
``fronts``         error against effort (:class:`train.studies.fronts.FrontConfig`)
``adversary``      adversarial disturbance search (:mod:`train.studies.adversary`)
``replay``         re-run the worst cases a search found (its ``worst.yml``)
``rates``          the control rate as a robustness axis (:class:`train.studies.rates.RatesConfig`)
``verdict``        every robot × random test path × preset (:mod:`train.studies.verdict_study`)
``report``         rewrite ``report.md`` of results folders from their episodes tables
``probe-actions``  how much of its action range a trained policy uses
``probe-authority``  whether a residual's authority can move the arm at all
=================  =====================================================================

A bad config, a missing file or a corrupt results folder exits with status 2 and one line
saying what is wrong; a failure while running exits with status 1 and one line
(``PTRACK_TRACEBACK=1`` shows the traceback); an interrupted run saves what it reached.
"""

from __future__ import annotations

# One BLAS thread per process, set before numpy loads: the sweeps fork their workers from
# a single-threaded process (train.common.runs.start_method).
from train.common.threads import one_thread_defaults

one_thread_defaults()

import argparse  # noqa: E402
import importlib  # noqa: E402
import os  # noqa: E402
import shlex  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from ptrack_gym.errors import PtrackError  # noqa: E402
from train.common.arguments import (  # noqa: E402
    add_config_arguments,
    config_from_args,
    split_assignment,
    to_argv,
    yaml_value,
)

Runner = Callable[[argparse.Namespace, argparse.ArgumentParser], int]


def _progress(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _resume(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--resume", action="store_true", help=f"continue the {what} in --out")
    parser.add_argument(
        "--force", action="store_true",
        help="start over in an --out that holds files (publishing to docs/results takes it)",
    )  # fmt: skip


def _config(cls: type, args: argparse.Namespace, command: str) -> Any:
    """The config of ``args``, stated before anything runs: where it came from and every
    field that differs from the dataclass's defaults."""
    cfg = config_from_args(cls, args)
    source = f"--config {args.config}" if args.config else f"no --config: {cls.__name__}'s defaults"
    fields = " ".join(shlex.quote(w) for w in to_argv(cfg)) or "(none)"
    print(f"ptrack {command}: {source}; fields set: {fields}", flush=True)
    return cfg


# -- evaluate ------------------------------------------------------------------------------
# -- the commands of one config dataclass ----------------------------------------------------
def _config_command(
    where: str,
    what: str,
    run: Callable[[Any, argparse.Namespace], Path | None],
    extra: Callable[[argparse.ArgumentParser], None] | None = None,
) -> tuple[Callable[[argparse.ArgumentParser], None], Runner]:
    """The parser builder and runner of a command whose config is the dataclass ``where``
    (``"module:Class"``): its generated arguments, ``--resume``/``--force`` (of ``what``),
    ``--no-progress`` and what ``extra`` adds; the runner states the config, then
    ``run(config, args)`` — a file it returns is printed."""
    module, _, name = where.partition(":")

    def config_class() -> type:
        return getattr(importlib.import_module(module), name)

    def build(p: argparse.ArgumentParser) -> None:
        add_config_arguments(p, config_class())
        _resume(p, what)
        _progress(p)
        if extra is not None:
            extra(p)

    def runner(args: argparse.Namespace, p: argparse.ArgumentParser) -> int:
        cfg = _config(config_class(), args, p.prog.removeprefix("ptrack "))
        shown = run(cfg, args)
        if shown is not None:
            print(shown.read_text())
        return 0

    return build, runner


def _run_evaluate(cfg: Any, a: argparse.Namespace) -> None:
    from train.evaluation.sweep import run_sweep

    run_sweep(cfg, **_resumable(a))


def _run_study(cfg: Any, a: argparse.Namespace) -> Path:
    from train.rl.study import run_study

    return run_study(cfg, **_resumable(a)) / "final.md"


def _run_fronts(cfg: Any, a: argparse.Namespace) -> None:
    from train.studies.fronts import run_fronts

    run_fronts(cfg, a.resume, not a.no_progress, force=a.force)


def _run_adversary(cfg: Any, a: argparse.Namespace) -> None:
    from train.studies.adversary import run_search

    run_search(cfg, a.resume, not a.no_progress, force=a.force)


def _run_verdict(cfg: Any, a: argparse.Namespace) -> Path:
    from train.studies.verdict_study import run_verdict

    return run_verdict(cfg, **_resumable(a)) / "verdict.md"


def _resumable(a: argparse.Namespace) -> dict[str, bool]:
    """The run options of a study whose rows record their gains (``--rerun-changed``)."""
    return {"resume": a.resume, "progress": not a.no_progress, "force": a.force,
            "rerun_changed": a.rerun_changed}  # fmt: skip


def _rerun_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--rerun-changed",
        action="store_true",
        help="with --resume: drop the rows of controllers whose gains changed since they ran "
        "(tuned again, other defaults; every model-based controller's in a folder written "
        "before gains were recorded) and run them again; without it such a resume is refused",
    )


def _run_rates(cfg: Any, a: argparse.Namespace) -> None:
    from train.studies.rates import run_study

    out = run_study(cfg, **_resumable(a))
    print((out / "report.md").read_text().split("## Where each controller holds")[-1])


# -- train -----------------------------------------------------------------------------------
def _train_parser(p: argparse.ArgumentParser) -> None:
    from train.rl.config import add_arguments

    add_arguments(p)


def _train(args: argparse.Namespace, p: argparse.ArgumentParser) -> int:
    from train.common.signals import sigterm_as_interrupt
    from train.rl.config import from_args
    from train.rl.config import to_argv as train_argv
    from train.rl.run import run

    cfg = from_args(args)  # on --resume, what was not given comes from the run
    source = f"--config {args.config}" if args.config else "no --config: TrainConfig's defaults"
    fields = " ".join(shlex.quote(w) for w in train_argv(cfg))
    print(f"ptrack train: {source}; fields set: {fields}", flush=True)
    with sigterm_as_interrupt():
        result = run(cfg, args.words)
    print(f"trained {result.num_timesteps} steps; run folder: {result.run_dir}")
    return 0


# -- studies ---------------------------------------------------------------------------------
def _tune_parser(p: argparse.ArgumentParser) -> None:
    from train.studies.tune import TuneConfig

    add_config_arguments(p, TuneConfig)
    p.add_argument("--resume", action="store_true", help="continue the studies in --out")
    p.add_argument(
        "--force", action="store_true",
        help="start over in an --out that holds files; with --resume (and --save): continue "
        "the studies and replace the shipped tuned gains",
    )  # fmt: skip
    p.add_argument("--save", action="store_true", help="write agents/tuned/<robot>-<c>.yml")
    p.add_argument("--table", action="store_true", help="print the tuned gains and exit")
    p.add_argument(
        "--status", action="store_true",
        help="print where the fight in --out stands (its studies, trials, best so far) and exit",
    )  # fmt: skip
    _progress(p)


def _tune(args: argparse.Namespace, p: argparse.ArgumentParser) -> int:
    from agents.registry import TUNED_DIR
    from train.studies.tune import TuneConfig, tune, tuned_table

    if args.table:
        print(tuned_table())
        return 0
    if args.status:
        from train.studies.tune_fight import journal_status

        print(journal_status(Path(config_from_args(TuneConfig, args).out)))
        return 0
    cfg = _config(TuneConfig, args, "tune")
    save = TUNED_DIR if args.save else None
    results = tune(cfg, args.resume, save, not args.no_progress, force=args.force)
    for controller, best in results.items():
        print(f"{controller}: {best}")
    return 0


def _replay_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("worst", type=Path, help="a search's worst.yml, or its folder")
    p.add_argument(
        "--under",
        nargs="+",
        default=[],
        metavar="CONTROLLER",
        help="also replay each worst case (same spec, start phase and seed) under these "
        "controllers: is it the controller's worst case, or the disturbance's?",
    )
    p.add_argument(
        "--rate",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="replay the searched controller with this gain rate changed (repeatable; value "
        "read as YAML), e.g. --rate damping_ratio=0.5 for the passivity law",
    )


def _replay(args: argparse.Namespace, p: argparse.ArgumentParser) -> int:
    from agents.registry import CONTROLLERS
    from ptrack_gym.errors import InvalidConfigError
    from train.studies.adversary import replay_all

    worst = args.worst / "worst.yml" if args.worst.is_dir() else args.worst
    if not worst.is_file():
        raise InvalidConfigError(f"{worst} does not exist: give a search's worst.yml or folder")
    unknown = sorted(set(args.under) - set(CONTROLLERS))
    if unknown:
        raise InvalidConfigError(
            f"unknown controller(s) {unknown} for --under; known: {sorted(CONTROLLERS)}"
        )
    rates = {}
    for item in args.rate:
        name, raw = split_assignment(item, "--rate", what="rate")
        rates[name] = yaml_value(raw, "--rate", name)
    for line in replay_all(worst, args.under, rates):
        print(line)
    return 0


# -- report ----------------------------------------------------------------------------------
def _report_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="+", type=Path, help="results folders (episodes.csv)")
    p.add_argument("--no-rewrite", action="store_true", help="only print each folder's headline")
    p.add_argument(
        "--against",
        type=Path,
        help="another evaluation's results folder: print whether it ranks the controllers "
        "as each folder does (leaders and Kendall's tau per shared condition, both metrics)",
    )
    p.add_argument(
        "--publish",
        metavar="NAME",
        help="copy the (one) folder's report into the docs site: docs/results/NAME_report.md, "
        "its figures to docs/figures/NAME_*.png, the image links rewritten",
    )


def results_kind(folder: Path) -> str:
    """ "evaluate" or "rates": which command wrote the results folder (its ``config.yml``).

    Raises:
        InvalidConfigError: the folder has no ``config.yml`` and ``episodes.csv`` of either.
    """
    import yaml

    from ptrack_gym.errors import InvalidConfigError

    saved = folder / "config.yml"
    if not (saved.exists() and (folder / "episodes.csv").exists()):
        raise InvalidConfigError(f"{folder}: no config.yml and episodes.csv of a sweep or study")
    keys = set(yaml.safe_load(saved.read_text()) or {})
    if "robots" in keys and "control_rates" in keys:
        return "rates"
    if {"env_id", "controllers", "disturbances"} <= keys:
        return "evaluate"
    raise InvalidConfigError(f"{saved}: neither an evaluation sweep's nor a rate study's")


def _report(args: argparse.Namespace, p: argparse.ArgumentParser) -> int:
    import yaml

    from train.common.arguments import RECORD_KEYS

    if args.publish is not None and len(args.folders) != 1:
        p.error("--publish takes one results folder")
    for folder in args.folders:
        kind = results_kind(folder)  # refuses a folder without results first
        saved = yaml.safe_load((folder / "config.yml").read_text())
        fields = {k: v for k, v in saved.items() if k not in RECORD_KEYS}
        if kind == "rates":
            from train.studies.rates import RatesConfig, write_report

            cfg = RatesConfig(**{**fields, "out": str(folder)})
            if not args.no_rewrite:
                write_report(cfg, folder)
            table = (folder / "report.md").read_text().split("## Where each controller holds")
            print(f"{folder / 'report.md'}: where each controller holds{table[-1]}")
        else:
            from train.evaluation.config import EvalConfig
            from train.evaluation.sweep import finish

            cfg = EvalConfig(**{**fields, "out": str(folder), "video": False})
            if not args.no_rewrite:
                finish(cfg, folder, show=False)
            print(f"{folder / 'report.md'}:\n")
            print(headline_of(folder, cfg.metric) + "\n")
            if args.against is not None:
                from train.evaluation.verdict import folder_agreement

                if results_kind(args.against) != "evaluate":
                    p.error(f"--against {args.against}: not an evaluation's results folder")
                print(folder_agreement(folder, args.against) + "\n")
        if args.publish is not None:
            from train.evaluation.publish import publish_report

            docs = Path(__file__).resolve().parents[1] / "docs"
            for path in publish_report(folder, args.publish, docs):
                print(f"published {path}")
    return 0


def headline_of(folder: Path, metric: str) -> str:
    """The headline table of an evaluation results folder (its ``summary.csv``)."""
    import pandas as pd

    from train.evaluation.results import headline_tables

    return headline_tables(pd.read_csv(folder / "summary.csv"), metric)


# -- commands with their own argument lists -----------------------------------------------
def _delegate(module: str) -> tuple[Callable[[argparse.ArgumentParser], None], Runner]:
    """A command whose module parses its own arguments (``main(argv)``)."""

    def own_arguments(p: argparse.ArgumentParser) -> None:
        """The module's ``main`` parses the arguments (``--help`` is its own)."""

    def run(args: argparse.Namespace, p: argparse.ArgumentParser) -> int:

        result = importlib.import_module(module).main(args.argv)
        return result if isinstance(result, int) else 0

    return own_arguments, run


COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Runner]] = {
    "evaluate": (
        "paired evaluation sweep",
        *_config_command("train.evaluation.config:EvalConfig", "sweep", _run_evaluate, _rerun_flag),
    ),
    "train": ("train one RL policy (SB3)", _train_parser, _train),
    "campaign": ("train the runs of a campaign file", *_delegate("train.rl.campaign")),
    "study": (
        "learning curves and final tables of RL runs",
        *_config_command("train.rl.study:StudyConfig", "evaluation", _run_study, _rerun_flag),
    ),
    "tune": ("equal-budget gain tuning (Optuna)", _tune_parser, _tune),
    "fronts": (
        "error against effort fronts",
        *_config_command("train.studies.fronts:FrontConfig", "sweep", _run_fronts),
    ),
    "adversary": (
        "adversarial disturbance search",
        *_config_command("train.studies.adversary:AdversaryConfig", "studies", _run_adversary),
    ),
    "replay": ("re-run the worst cases of a search", _replay_parser, _replay),
    "rates": (
        "the control rate as a robustness axis",
        *_config_command("train.studies.rates:RatesConfig", "study", _run_rates, _rerun_flag),
    ),
    "verdict": (
        "the verdict across robots and random test paths",
        *_config_command(
            "train.studies.verdict_study:VerdictConfig", "study", _run_verdict, _rerun_flag
        ),
    ),
    "report": ("rewrite and print results folders' reports", _report_parser, _report),
    "probe-actions": (
        "action usage of trained policies",
        *_delegate("train.studies.action_probe"),
    ),
    "probe-authority": (
        "authority of a residual over its base",
        *_delegate("train.studies.authority_probe"),
    ),
}


def build_parser(command: str) -> argparse.ArgumentParser:
    """The parser of ``ptrack <command>``."""
    summary, build, _ = COMMANDS[command]
    parser = argparse.ArgumentParser(prog=f"ptrack {command}", description=summary)
    build(parser)
    return parser


def _top_parser() -> argparse.ArgumentParser:
    listing = "\n".join(f"  {name:<16} {summary}" for name, (summary, _, _) in COMMANDS.items())
    parser = argparse.ArgumentParser(
        prog="ptrack",
        description=__doc__.splitlines()[0],
        epilog=f"commands:\n{listing}\n\n'ptrack COMMAND --help' lists a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("command", choices=list(COMMANDS), metavar="COMMAND")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``ptrack`` with ``argv`` (default: the process's arguments); return the exit
    status. A :class:`~ptrack_gym.errors.PtrackError` is a usage error (status 2, one line);
    an interruption (Ctrl-C, SIGINT) says how to continue and returns 130.
    Only the command's own modules are imported (``ptrack --help`` stays quick)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:
        _top_parser().parse_args(argv[:1])  # prints the help, or the unknown command
        return 2
    command, words = argv[0], argv[1:]
    _, build, run = COMMANDS[command]
    parser = build_parser(command) if build.__name__ != "own_arguments" else None
    if parser is None:  # the module parses its own arguments
        return run(argparse.Namespace(argv=words), argparse.ArgumentParser(prog=command))
    args = parser.parse_args(words)
    args.words = words  # as typed: the provenance of a run (command.txt)
    try:
        return run(args, parser)
    except PtrackError as exc:
        if isinstance(exc, (ValueError, TypeError)):  # a usage error: one line, status 2
            parser.error(str(exc))
        print(f"ptrack {command}: failed: {exc}", file=sys.stderr)  # e.g. a diverged run
        return 1
    except FileNotFoundError as exc:  # a path the user gave
        parser.error(f"{exc.filename}: no such file or folder")
    except KeyboardInterrupt:  # Ctrl-C, or SIGINT from a scheduler's time limit
        print(
            f"ptrack {command}: interrupted; what it wrote is kept (its results files are "
            "appended as it goes; the same command with --resume continues)",
            file=sys.stderr,
        )
        return 130
    except Exception as exc:  # a run-time failure: one line, status 1
        if os.environ.get("PTRACK_TRACEBACK"):
            raise
        print(
            f"ptrack {command}: failed: {type(exc).__name__}: {exc} "
            "(PTRACK_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 1
    return 2  # not reached: parser.error exits


def run_command(command: str, argv: Sequence[str] | None = None) -> int:
    """``ptrack <command> <argv>``: the entry of ``python -m train.evaluate`` and
    ``python -m train.train``."""
    return main([command, *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
