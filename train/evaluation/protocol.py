"""What each learned entrant (``sb3:<run folder>``) trained on — algorithm, env steps,
paths, disturbance families, mass randomisation — for every report that judges one
(issue 39: the protocol "written into every run's config and every report")."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ptrack_gym.errors import InvalidConfigError
from train.evaluation.policies import SB3_PREFIX


def _run(name: str) -> dict[str, Any] | None:
    """The ``config.yml`` of entrant ``name``; None where its run folder is not here (a
    report redrawn from committed episodes, the runs gone)."""
    from train.evaluation.policies import run_config, sb3_files

    try:
        return dict(run_config(sb3_files(name)[0]))
    except (OSError, InvalidConfigError):
        return None


def trained_env_steps(name: str) -> int:
    """Env steps entrant ``name`` trained: its last checkpoint (``sb3:<run>@<steps>``: those
    steps; else the run's newest ``checkpoints/rl_model_<k>_steps.zip``; a shipped model
    without checkpoints: its run's ``derived.steps``) × its decision period (checkpoints
    count decisions); 0 where neither is known."""
    from train.common.checkpoint_files import latest_checkpoint

    run = _run(name) or {}
    folder, _, at = name.removeprefix(SB3_PREFIX).partition("@")
    if at.isdigit():
        last = int(at)
    else:
        found = latest_checkpoint(Path(folder))
        last = found[0] if found else int((run.get("derived") or {}).get("steps") or 0)
    return last * int((run.get("config") or {}).get("decision_every", 1))


def tuning_env_steps(robot: str, controller: str) -> int | None:
    """The env steps the tuning fight spent on ``controller`` of ``robot`` (its tuned file's
    ``study.env_steps``, as the file stands now: a later fight's file replaces the one a
    run trained with); None without a file, or for a file of an older protocol."""
    import yaml

    from agents.registry import TUNED_DIR

    path = TUNED_DIR / f"{robot}-{controller}.yml"
    if not path.exists():
        return None
    steps = ((yaml.safe_load(path.read_text()) or {}).get("study") or {}).get("env_steps")
    return None if steps is None else int(steps)


def _deploy_gate(name: str, config: dict[str, Any]) -> str:
    """The distance gate a run acts behind (its ``deploy.yml``'s, else its training
    config's), or "–"."""
    from train.evaluation.policies import deploy_safeguards, sb3_files

    gate = deploy_safeguards(sb3_files(name)[0]) or config
    if gate.get("gate_rad") is None:
        return "–"
    return (
        f"a gate of {1e3 * gate['gate_rad']:g} mrad past a "
        f"{1e3 * (gate.get('gate_deadband_rad') or 0.0):g}-mrad deadband"
    )


def protocol_markdown(entrants: Sequence[str]) -> str:
    """Markdown: what each entrant trained on — robot, algorithm, env steps (beside those the
    tuning fight spent on a tuned base: :func:`tuning_env_steps`), paths, disturbance
    families, mass randomisation — and the distance gate it is deployed behind (issue 39's
    protocol, in the report that judges it)."""
    lines = [
        "| entrant | robot | algorithm | env steps | tuning of its base (env steps) "
        "| trained on paths | trained under | randomized masses | deployed behind |",
        "|---|---|---|---:|---:|---|---|---:|---|",
    ]
    for name in entrants:
        run = _run(name)
        if run is None:
            lines.append(f"| {name} | – | – | – | – | (its run folder is not here) | – | – | – |")
            continue
        c, robot = run["config"], (run.get("derived") or {}).get("robot", "–")
        tuned = (
            tuning_env_steps(robot, c["residual"])
            if c.get("residual") not in (None, "none", "network") and c.get("base_gains") == "tuned"
            else None
        )
        lines.append(
            f"| {name} | {robot} | {c.get('algo', 'sac')} | {trained_env_steps(name)} "
            f"| {'–' if tuned is None else tuned} "
            f"| {c.get('train_paths') or 'the default path'} "
            f"| {c.get('train_families') or c.get('disturbance', 'none')} "
            f"| ±{float(c.get('randomize_mass', 0.0)):g} | {_deploy_gate(name, c)} |"
        )
    return "\n".join(lines)


def protocol_section(controllers: Sequence[str]) -> list[str]:
    """A report's lines on what its learned entrants (``sb3:…`` among ``controllers``)
    trained on; none without one."""
    names = [c for c in controllers if str(c).startswith(SB3_PREFIX)]
    if not names:
        return []
    return ["", "## What the learned entrants trained on", "", protocol_markdown(names), ""]
