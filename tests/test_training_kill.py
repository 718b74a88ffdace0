"""A training run killed at any moment resumes: ``hyperbones train`` killed with SIGKILL at
random moments and in the middle of its checkpoint writes, resumed with ``--resume`` each
time, loses at most one checkpoint interval and finishes clean; and every point at which a
save can stop leaves a checkpoint that resumes."""

import math
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from hyperbones.models.loading import load_checkpoint
from hyperbones.training.checkpoint import load_optimizer_state, optimizer_path, save_training_state
from test_training_trainer import TINY_TOML

STEPS, EVERY = 48, 4

# The trainer tests' tiny teacher config, run longer (``train --set``).
OVERRIDES = [f"train.steps={STEPS}", f"train.checkpoint_every={EVERY}", "train.rollout_max=2",
             "train.rollout_ramp_steps=2"]

# `hyperbones train` as the CLI runs it, noting in a journal (one unbuffered append per line, so
# a SIGKILL loses none) each step it reaches and each save it begins and ends. Its checkpoint
# files are small and written in a millisecond; here each is written in pieces, so that its
# temporary file stays on disk long enough for the test to kill the run in mid-write.
JOURNALED_TRAIN = """
import io
import os
import sys
import time

import torch

from hyperbones.cli import main
from hyperbones.training.trainer import TeacherTrainer

journal = os.open(sys.argv[1], os.O_WRONLY | os.O_CREAT | os.O_APPEND)
real_save, real_torch_save, real_advance, real_train = (TeacherTrainer.save, torch.save, TeacherTrainer._advance,
                                                        TeacherTrainer.train)


def note(text):
    os.write(journal, (text + "\\n").encode())


def save_in_pieces(payload, path, *args, **kwargs):
    buffer = io.BytesIO()
    real_torch_save(payload, buffer, *args, **kwargs)
    data = buffer.getvalue()
    with open(path, "wb") as file:
        for start in range(0, len(data), len(data) // 4 + 1):
            file.write(data[start:start + len(data) // 4 + 1])
            file.flush()
            time.sleep(0.03)


def save(self):
    note(f"begin {self.step}")
    torch.save = save_in_pieces
    try:
        real_save(self)
    finally:
        torch.save = real_torch_save
    note(f"end {self.step}")


def advance(self):
    logs = real_advance(self)
    note(f"step {self.step + 1} {logs['loss']}")
    return logs


def train(self):
    note(f"start {self.step}")
    return real_train(self)


TeacherTrainer.save, TeacherTrainer._advance, TeacherTrainer.train = save, advance, train
sys.exit(main(sys.argv[2:]))
"""


def read_journal(path: Path) -> list[tuple[str, int, float]]:
    """(what, step, loss) per line; a last line cut short by the kill is left out."""
    entries = []
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) >= 2:
            entries.append((parts[0], int(parts[1]), float(parts[2]) if len(parts) > 2 else math.nan))
    return entries


def temporaries(run: Path, prefix: str) -> set[str]:
    return {entry.name for entry in os.scandir(run) if entry.name.startswith(prefix) and ".tmp" in entry.name}


def test_train_killed_at_random_moments_resumes(tmp_path, body):
    """Four SIGKILLs: two at random steps, one while the optimiser state is being written and
    one while the checkpoint is (the optimiser state of the new step already written)."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_TOML)
    script = tmp_path / "journaled_train.py"
    script.write_text(JOURNALED_TRAIN)
    run, journal = tmp_path / "run", tmp_path / "journal.txt"
    command = [sys.executable, str(script), str(journal), "train", "--config", str(config), "--out", str(run),
               *(f"--set={override}" for override in OVERRIDES),
               "--quiet", "--resume"]  # --resume with no checkpoint yet starts afresh
    env = dict(os.environ, OMP_NUM_THREADS="1")
    rng = random.Random(7)
    saved_step = 0  # the checkpoint's step after the last kill
    for plan in ("random", ".optimizer.", ".checkpoint.", "random"):
        seen = len(read_journal(journal)) if journal.exists() else 0
        process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # A random kill comes at a random step past this attempt's first save; a mid-write
        # kill at the first or second temporary file of its kind that appears.
        kill_after = rng.randint(EVERY + 1, 3 * EVERY) if plan == "random" else rng.randint(1, 2)
        written: set[str] = set()
        start = None
        deadline = time.monotonic() + 120
        while True:
            assert process.poll() is None, f"the run ended before its kill ({plan}): {process.communicate()[1][-3000:]}"
            assert time.monotonic() < deadline, f"no moment to kill ({plan})"
            entries = read_journal(journal)[seen:] if journal.exists() else []
            if start is None and entries:
                start = entries[0][1]
            if plan == "random":
                if any(what == "step" and step >= start + kill_after for what, step, _ in entries):
                    time.sleep(rng.uniform(0.0, 0.2))
                    break
            elif run.exists():
                written |= temporaries(run, plan)
                if len(written) >= kill_after:
                    break
            time.sleep(0.002)
        process.send_signal(signal.SIGKILL)
        process.communicate()
        entries = read_journal(journal)[seen:]
        assert entries[0][:2] == ("start", saved_step)  # every resume starts, from the checkpoint left
        if plan != "random":
            assert temporaries(run, plan), "the kill was meant to come in the middle of a write"

        # The checkpoint and its optimiser state load, and at most one interval of steps is lost.
        payload = load_checkpoint(run / "checkpoint.pt")
        assert load_optimizer_state(run / "checkpoint.pt", payload)["state"]
        history = read_journal(journal)
        completed = [step for what, step, _ in history if what == "end"]
        begun = [step for what, step, _ in history if what == "begin"]
        # The last save that finished, or the one the kill cut short if it got as far as the checkpoint.
        assert payload["step"] in (completed[-1], begun[-1]), plan
        reached = max(step for what, step, _ in entries if what == "step")
        assert payload["step"] >= reached - EVERY, plan
        saved_step = payload["step"]

    seen = len(read_journal(journal))
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"trained to step {STEPS}" in done.stdout
    entries = read_journal(journal)
    assert entries[seen][:2] == ("start", saved_step)
    assert all(math.isfinite(loss) for what, _, loss in entries if what == "step")
    payload = load_checkpoint(run / "checkpoint.pt")
    assert payload["step"] == STEPS
    assert torch.load(optimizer_path(run / "checkpoint.pt"), weights_only=True)["step"] == STEPS
    # No temporary or staged file is left once a save has finished.
    assert sorted(entry.name for entry in run.iterdir()) == ["checkpoint.pt", "optimizer.pt", "tensorboard"]
    # The TensorBoard log holds every step once, however often the run was killed.
    from hyperbones.training.summary import read_log

    losses = read_log(run / "tensorboard")["loss"]
    assert sorted(step for step, _, _ in losses) == list(range(1, STEPS + 1))
    assert all(math.isfinite(value) for _, _, value in losses)


class Killed(BaseException):
    """Stands for the process dying at the n-th file replacement of a save."""


@pytest.mark.parametrize("dies_at", range(4))
def test_save_stopped_at_each_rename_resumes(tmp_path, monkeypatch, dies_at):
    """A save that stops before any of its renames (or completes, ``dies_at`` past the last)
    leaves a checkpoint whose optimiser state loads: the old pair or the new one."""
    path = tmp_path / "checkpoint.pt"
    model = {"weight": torch.zeros(3)}
    optimizer = {"state": {0: {"exp_avg": torch.zeros(3)}}, "param_groups": [{"params": [0]}]}

    save_training_state(path, model, dict(model), optimizer, 4, {"train": {}})
    renames, real_replace = [], os.replace

    def replace(source, target):
        if len(renames) == dies_at:
            raise Killed
        renames.append(target)
        real_replace(source, target)

    monkeypatch.setattr(os, "replace", replace)
    newer = {**optimizer, "state": {0: {"exp_avg": torch.ones(3)}}}
    try:
        save_training_state(path, {"weight": torch.ones(3)}, {"weight": torch.ones(3)}, newer, 8, {"train": {}})
    except Killed:
        pass
    monkeypatch.setattr(os, "replace", real_replace)
    payload = load_checkpoint(path)
    state = load_optimizer_state(path, payload)
    assert payload["step"] in (4, 8)
    assert float(state["state"][0]["exp_avg"][0]) == float(payload["model"]["weight"][0])

    # The next save leaves only the checkpoint and its optimiser state.
    save_training_state(path, model, dict(model), optimizer, 12, {"train": {}})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt", "optimizer.pt"]
    assert torch.equal(load_optimizer_state(path, load_checkpoint(path))["state"][0]["exp_avg"], torch.zeros(3))
