"""Interruptions of a training run (``train.common.signals``): a signal that arrives while a
file is saved waits for the save, then does what it would have done; a run stopped during a
checkpoint's save still saves ``model.zip`` and a whole checkpoint."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from train.common.signals import sigterm_as_interrupt, uninterrupted

ROOT = Path(__file__).resolve().parents[1]


def test_sigterm_in_a_save_waits_for_it_then_interrupts() -> None:
    reached = []
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        with uninterrupted():
            signal.raise_signal(signal.SIGTERM)
            reached.append("the rest of the save")
        reached.append("after the save")  # not reached: the held signal interrupts here
    assert reached == ["the rest of the save"]
    assert signal.getsignal(signal.SIGTERM) is previous


def test_ctrl_c_in_a_save_waits_for_it_then_interrupts() -> None:
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with uninterrupted():
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)  # twice: delivered once
            reached.append("saved")
    assert reached == ["saved"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_nothing_held_nothing_raised_and_the_handlers_come_back() -> None:
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with uninterrupted():
        assert signal.getsignal(signal.SIGINT) is not before[signal.SIGINT]
    assert {s: signal.getsignal(s) for s in before} == before


def test_an_ignored_signal_stays_ignored() -> None:
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        with uninterrupted():
            signal.raise_signal(signal.SIGTERM)
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_blocks_nest_and_a_failed_save_still_delivers_the_signal() -> None:
    order = []
    with pytest.raises(KeyboardInterrupt) as info, sigterm_as_interrupt():
        with uninterrupted():
            with uninterrupted():
                signal.raise_signal(signal.SIGTERM)
                order.append("inner")
            order.append("outer")  # the inner block handed the signal to the outer one
            raise OSError("disk full")
    assert order == ["inner", "outer"]
    assert isinstance(info.value.__context__, OSError)  # the save's error is kept, chained


def test_outside_the_main_thread_the_block_just_runs() -> None:
    seen = []

    def save() -> None:
        with uninterrupted():
            seen.append(signal.getsignal(signal.SIGINT))

    t = threading.Thread(target=save)
    t.start()
    t.join()
    assert seen == [signal.default_int_handler]


def test_sigterm_default_action_still_ends_the_process_after_the_save(tmp_path: Path) -> None:
    """Held, not swallowed: under SIGTERM's default action the process still ends (-15),
    once the file is whole."""
    code = (
        "import os, signal, sys; from pathlib import Path\n"
        "from train.common.signals import uninterrupted\n"
        "with uninterrupted():\n"
        "    signal.raise_signal(signal.SIGTERM)\n"
        f"    Path({str(tmp_path / 'saved')!r}).write_text('whole')\n"
        f"Path({str(tmp_path / 'after')!r}).write_text('not reached')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True)
    assert proc.returncode == -signal.SIGTERM, proc.stderr
    assert (tmp_path / "saved").read_text() == "whole"
    assert not (tmp_path / "after").exists()


def test_a_run_stopped_in_the_middle_of_a_checkpoint_saves_model_zip_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGTERM while ``torch.save`` writes the 60-step checkpoint (where a campaign's worker
    was stopped when the test that sends SIGTERM to a campaign failed: ``torch.save`` cut
    short raised RuntimeError, which no ``except KeyboardInterrupt`` caught, and the run
    saved nothing more): the checkpoint is finished, then the run saves ``model.zip`` and
    a checkpoint at the step it reached, and ``--resume`` continues from there."""
    pytest.importorskip("stable_baselines3")
    import zipfile

    from stable_baselines3 import SAC

    from tests.test_train import argv
    from train.rl.checkpoints import latest_checkpoint
    from train.rl.config import parse_args
    from train.rl.run import run

    out = tmp_path / "run"
    real_write, writes = zipfile._ZipWriteFile.write, []  # type: ignore[attr-defined]

    def stopped_mid_save(self, data):  # type: ignore[no-untyped-def]
        writes.append(len(data))
        if len(writes) == 3:  # torch.save has written a part of the zip's tensors
            os.kill(os.getpid(), signal.SIGTERM)
        return real_write(self, data)

    monkeypatch.setattr(zipfile._ZipWriteFile, "write", stopped_mid_save)
    cmd = argv(out, "sac", "none", 1000, "--eval-freq", "0", "--checkpoint-freq", "60")
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        run(parse_args(cmd))
    monkeypatch.setattr(zipfile._ZipWriteFile, "write", real_write)
    steps, ckpt = latest_checkpoint(out)  # type: ignore[misc]
    assert steps == 60 and SAC.load(ckpt).num_timesteps == 60  # whole, loadable
    assert SAC.load(out / "model.zip").num_timesteps == 60
    assert (out / "checkpoints" / "rl_model_replay_buffer_60_steps.pkl").is_file()
    resumed = run(parse_args([*argv(out, "sac", "none", 40, "--eval-freq", "0"), "--resume"]))
    assert resumed.num_timesteps == 100


def test_the_evaluations_best_model_is_still_saved(tmp_path: Path) -> None:
    """``best_model.zip`` comes from SaveBestModel (EvalCallback's callback_on_new_best)
    now, not from the EvalCallback's own save: it is written at the first evaluation."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC

    from tests.test_train import argv
    from train.rl.config import parse_args
    from train.rl.run import run

    out = tmp_path / "run"
    run(parse_args(argv(out, "sac", "none", 60, "--eval-freq", "50")))
    assert SAC.load(out / "best_model.zip").num_timesteps == 50


def test_every_held_signal_is_delivered_even_after_one_raises(tmp_path: Path) -> None:
    """Ctrl-C then SIGTERM (at its default action) held by one save: the first raises
    KeyboardInterrupt, and the second still ends the process."""
    code = (
        "import signal\n"
        "from train.common.signals import uninterrupted\n"
        "try:\n"
        "    with uninterrupted():\n"
        "        signal.raise_signal(signal.SIGINT)\n"
        "        signal.raise_signal(signal.SIGTERM)\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "print('survived')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == -signal.SIGTERM and "survived" not in proc.stdout


def test_an_ignored_or_foreign_handler_is_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """SIG_IGN stays installed through the block (no handler of its own to interrupt a
    system call); a handler Python did not install (``getsignal`` None) is not replaced,
    so nothing tries to restore None."""
    real = signal.getsignal
    monkeypatch.setattr(signal, "getsignal", lambda s: None if s == signal.SIGINT else real(s))
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        with uninterrupted():
            assert real(signal.SIGTERM) == signal.SIG_IGN
            assert real(signal.SIGINT) is signal.default_int_handler  # untouched
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_save_cut_short_leaves_the_old_file_whole(tmp_path: Path) -> None:
    """A process killed in the middle of a save (a save that stops part-way stands in for
    it) leaves the file under its name as it was: only a temporary beside it is
    half-written (and removed where the process lives on to see the error)."""
    from train.common.runs import saved_whole

    target = tmp_path / "model.zip"
    target.write_text("the old, whole model")

    def killed(path: Path) -> None:
        path.write_text("half of the new")
        raise SystemExit("killed")

    with pytest.raises(SystemExit):
        saved_whole(target, killed)
    assert target.read_text() == "the old, whole model"
    assert sorted(tmp_path.iterdir()) == [target]  # the cut temporary is gone too
    saved_whole(target, lambda p: p.write_text("the new model"))
    assert target.read_text() == "the new model" and sorted(tmp_path.iterdir()) == [target]


def test_a_checkpoint_zip_appears_only_after_its_replay_buffer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The zip marks a whole checkpoint: a run killed while the replay buffer of its next
    checkpoint is written still resumes from the last whole one."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC

    from tests.test_train import argv
    from train.rl.checkpoints import latest_checkpoint
    from train.rl.config import parse_args
    from train.rl.run import run

    out = tmp_path / "run"
    run(parse_args(argv(out, "sac", "none", 60, "--eval-freq", "0", "--checkpoint-freq", "60")))
    assert latest_checkpoint(out)[0] == 60  # type: ignore[index]

    def killed(self, path):  # type: ignore[no-untyped-def]
        Path(path).write_bytes(b"half a buffer")
        raise SystemExit("killed")

    monkeypatch.setattr(SAC, "save_replay_buffer", killed)
    with pytest.raises(SystemExit):
        run(parse_args([*argv(out, "sac", "none", 60, "--eval-freq", "0", "--checkpoint-freq",
                              "60"), "--resume"]))  # fmt: skip
    steps, path = latest_checkpoint(out)  # type: ignore[misc]
    assert steps == 60 and SAC.load(path).num_timesteps == 60
    assert not (out / "checkpoints" / "rl_model_120_steps.zip").exists()
