"""Names of a training run's checkpoint files, without SB3 or torch.

``<run>/checkpoints/rl_model_<steps>_steps.zip`` is what SB3's ``CheckpointCallback`` writes
with ``name_prefix="rl_model"``; ``<steps>`` counts the agent's decisions (calls of
``env.step`` on the trained env), not simulator steps. Kept here, torch-free, so that the
studies (``train.studies``) and the RL runs (``train.rl``) read one naming.
"""

from __future__ import annotations

import re
from pathlib import Path

CHECKPOINT_PREFIX = "rl_model"
CHECKPOINT_RE = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps\.zip$")
REPLAY_RE = re.compile(rf"^{CHECKPOINT_PREFIX}_replay_buffer_(\d+)_steps\.pkl$")


def latest_checkpoint(run_dir: Path) -> tuple[int, Path] | None:
    """(steps, path) of the newest ``checkpoints/rl_model_<steps>_steps.zip``, or None."""
    folder = Path(run_dir) / "checkpoints"
    if not folder.is_dir():
        return None
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := CHECKPOINT_RE.match(p.name))]
    return max(found) if found else None
