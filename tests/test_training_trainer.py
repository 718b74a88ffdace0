"""hyperbones train: a few real steps on a tiny garment, checkpoints, resume, two DDP processes."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.models.loading import load_checkpoint
from hyperbones.training.checkpoint import export_weights
from hyperbones.training.config import TeacherTrainingConfig
from hyperbones.training.loss import collision_weight_at
from hyperbones.models.loading import teacher_from_checkpoint
from hyperbones.training.trainer import TeacherTrainer, learning_rate_at, rollout_length

TINY = {"model": {"latent": 16, "blocks": 2},
        "data": {"templates": ["tshirt"], "resolutions": [1000], "train_clips": [], "builtins": ["walk"],
                 "hold_seconds": 0.5},
        "train": {"steps": 4, "checkpoint_every": 2, "log_every": 1, "rollout_max": 2, "rollout_ramp_steps": 2}}

TINY_TOML = """
[model]
latent = 16
blocks = 2
[data]
templates = ["tshirt"]
resolutions = [1000]
train_clips = []
builtins = ["walk"]
hold_seconds = 0.5
[train]
steps = 3
checkpoint_every = 3
log_every = 1
"""


def test_ramps():
    assert collision_weight_at(0, 5e3, 5e5, 100) == 5e3
    assert collision_weight_at(50, 5e3, 5e5, 100) == pytest.approx(5e4)
    assert collision_weight_at(500, 5e3, 5e5, 100) == 5e5
    config = TeacherTrainingConfig().train
    assert rollout_length(0, config) == config.rollout_start
    assert rollout_length(10 * config.rollout_ramp_steps, config) == config.rollout_max
    staircase = TeacherTrainingConfig.from_dict({"train": {"learning_rate": 1e-4, "learning_rate_halve_at": [10, 20]}})
    assert [learning_rate_at(step, staircase.train) for step in (0, 9, 10, 19, 20, 10**6)] == pytest.approx(
        [1e-4, 1e-4, 5e-5, 5e-5, 2.5e-5, 2.5e-5])


def test_train_steps_checkpoint_and_resume(tmp_path, body):
    config = TeacherTrainingConfig.from_dict(TINY)
    trainer = TeacherTrainer(config, tmp_path / "run", progress=False, max_steps=2)
    before = [p.detach().clone() for p in trainer.model.parameters()]
    logs = trainer._advance()  # the settling step of a fresh episode
    assert logs["settle"] == 1.0 and all(torch.isfinite(torch.tensor(v)) for v in logs.values())
    trainer.step += 1
    assert trainer.train() == 2
    trainer.close()
    assert any(not torch.equal(a, b) for a, b in zip(before, trainer.model.parameters()))
    payload = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert payload["step"] == 2 and payload["config"] == config.as_dict()
    # The weights' moving average moved from the start towards the weights, not onto them.
    name = next(n for n, _ in trainer.model.named_parameters())
    average, start, now = payload["ema"][name], before[0], payload["model"][name]
    assert not torch.equal(average, start) and not torch.equal(average, now)
    assert float((average - start).norm()) < float((now - start).norm())
    assert torch.equal(payload["ema"]["node_normalizer.sum"], payload["model"]["node_normalizer.sum"])
    model, _ = teacher_from_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert torch.equal(model.state_dict()[name], average)
    assert list((tmp_path / "run" / "tensorboard").iterdir())

    # The optimiser's state sits beside the checkpoint; buffers equal to the model's are
    # left out of the stored moving average (load_checkpoint fills them back in).
    raw = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert "optimizer" not in raw and "node_normalizer.sum" not in raw["ema"]
    assert torch.load(tmp_path / "run" / "optimizer.pt", weights_only=True)["step"] == 2

    with pytest.raises(ParameterError, match="--resume"):
        TeacherTrainer(config, tmp_path / "run", progress=False)
    resumed = TeacherTrainer(config, tmp_path / "run", resume=True, progress=False)
    assert resumed.step == 2
    assert all(torch.equal(a, b) for a, b in zip(resumed.model.parameters(), trainer.model.parameters()))
    assert resumed.train() == 4
    resumed.close()
    assert load_checkpoint(tmp_path / "run" / "checkpoint.pt")["step"] == 4

    # An optimiser state from another step is refused; an older checkpoint with the state inside resumes.
    state = torch.load(tmp_path / "run" / "optimizer.pt", weights_only=True)
    torch.save({**state, "step": 3}, tmp_path / "run" / "optimizer.pt")
    with pytest.raises(InputFileError, match="optimizer.pt: from step 3, but the checkpoint is at step 4"):
        TeacherTrainer(config, tmp_path / "run", resume=True, progress=False)
    torch.save({**torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True), "optimizer": state["optimizer"]},
               tmp_path / "run" / "checkpoint.pt")
    (tmp_path / "run" / "optimizer.pt").unlink()
    older = TeacherTrainer(config, tmp_path / "run", resume=True, progress=False)
    assert older.step == 4 and older.optimizer.state
    older.close()

    other = TeacherTrainingConfig.from_dict({**TINY, "train": {**TINY["train"], "learning_rate": 1e-3}})
    with pytest.raises(ParameterError, match="different config"):
        TeacherTrainer(other, tmp_path / "run", resume=True, progress=False)

    slim = export_weights(tmp_path / "run" / "checkpoint.pt", tmp_path / "teacher.pt")
    assert "optimizer" not in torch.load(slim, weights_only=True)
    card = (tmp_path / "teacher.md").read_text()
    assert "Step 4," in card and "h of wall-clock time" in card and "| 1–" in card
    # The log summary stops at the step asked for, though the log goes on.
    from hyperbones.training.summary import read_log, training_summary

    log = read_log(tmp_path / "run" / "tensorboard")
    first = min(step for step, _, _ in log["loss"])
    assert training_summary(log, rows=1, up_to=first).splitlines()[-1].startswith(f"| 1–{first} |")
    assert training_summary(log, up_to=first - 1) == "(no training steps logged)"

    # A second stage starts from the first one's weights, at step 0 with a fresh optimiser.
    stage_two = TeacherTrainingConfig.from_dict(
        {**TINY, "train": {**TINY["train"], "init_from": str(tmp_path / "run" / "checkpoint.pt")}})
    fine_tune = TeacherTrainer(stage_two, tmp_path / "stage-two", progress=False)
    assert fine_tune.step == 0 and not fine_tune.optimizer.state
    assert all(torch.equal(a, b) for a, b in zip(fine_tune.model.state_dict().values(),
                                                 resumed.model.state_dict().values()))
    fine_tune.close()
    wider = TeacherTrainingConfig.from_dict({**TINY, "model": {"latent": 32, "blocks": 2},
                                             "train": stage_two.as_dict()["train"]})
    with pytest.raises(ParameterError, match="init_from has model"):
        TeacherTrainer(wider, tmp_path / "stage-three", progress=False)


# `hyperbones train` as the CLI runs it, with each rank writing its model's parameters when
# training starts (after DDP's start-up broadcast) and when it closes.
DDP_RANK_DUMPS = """
import sys
from pathlib import Path

import torch

from hyperbones.cli import main
from hyperbones.training.trainer import TeacherTrainer

out = Path(sys.argv[1])
train, close = TeacherTrainer.train, TeacherTrainer.close


def parameters(trainer):
    return {name: value.detach().cpu().clone() for name, value in trainer.model.named_parameters()}


def dumping_train(self):
    torch.save(parameters(self), out / f"start-rank{self.rank}.pt")
    return train(self)


def dumping_close(self, finished=True):
    torch.save(parameters(self), out / f"end-rank{self.rank}.pt")
    close(self, finished)


TeacherTrainer.train, TeacherTrainer.close = dumping_train, dumping_close
sys.exit(main(sys.argv[2:]))
"""


def test_two_process_ddp_training(tmp_path, body):
    """Two ranks on different episodes (seeds differ by rank) step together: they start from
    rank 0's weights and end with the same weights, which moved."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_TOML)
    script = tmp_path / "train_dumping.py"
    script.write_text(DDP_RANK_DUMPS)
    dumps = tmp_path / "dumps"
    dumps.mkdir()
    env = dict(os.environ, OMP_NUM_THREADS="1")
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(script),
               str(dumps), "train", "--config", str(config), "--out", str(tmp_path / "ddp"), "--quiet"]
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr[-3000:]
    payload = load_checkpoint(tmp_path / "ddp" / "checkpoint.pt")
    assert payload["step"] == 3
    assert "trained to step 3" in done.stdout
    start, end = ([torch.load(dumps / f"{when}-rank{rank}.pt", weights_only=True) for rank in (0, 1)]
                  for when in ("start", "end"))
    names = list(start[0])
    assert names and set(end[0]) == set(end[1]) == set(start[1]) == set(names)
    assert all(torch.equal(start[0][name], start[1][name]) for name in names)  # DDP's broadcast of rank 0's
    assert all(torch.equal(end[0][name], end[1][name]) for name in names)  # the averaged gradients
    assert any(not torch.equal(end[0][name], start[0][name]) for name in names)  # training moved them
    assert all(torch.equal(end[0][name], payload["model"][name]) for name in names)  # rank 0 saved its own
