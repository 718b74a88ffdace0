"""simulate --method teacher: an autoregressive rollout of a (tiny, briefly trained) checkpoint."""

import json
from pathlib import Path

import pytest
import torch

from hyperbones.cli import main
from hyperbones.jobs.simulate import run_simulation
from hyperbones.training.config import TeacherTrainingConfig
from hyperbones.training.trainer import TeacherTrainer
from test_training_trainer import TINY


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory, body):
    run = tmp_path_factory.mktemp("teacher") / "run"
    trainer = TeacherTrainer(TeacherTrainingConfig.from_dict(TINY), run, progress=False, max_steps=2)
    trainer.train()
    trainer.close()
    return run / "checkpoint.pt"


def test_teacher_rollout(tiny_checkpoint):
    result = run_simulation("teacher", "tshirt", "walk", None, frames=6, vertices=1000, checkpoint=str(tiny_checkpoint),
                            device="cpu")
    assert result.garment_vertices.shape == (6, result.garment.num_vertices, 3)
    assert torch.isfinite(result.garment_vertices).all()
    assert result.metrics["method"] == "teacher" and result.metrics["frames"] == 6
    # Pinned-free tshirt: every vertex is simulated, so the frames differ from one another.
    assert float((result.garment_vertices[-1] - result.garment_vertices[0]).abs().max()) > 0


def test_simulate_and_bench_commands(tiny_checkpoint, tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", "--method", "teacher", "--checkpoint", str(tiny_checkpoint), "--garment", "tshirt",
                 "--vertices", "1000", "--frames", "4", "--out", str(out), "--no-preview", "--quiet"]) == 0
    assert json.loads((out / "metrics.json").read_text())["method"] == "teacher"
    record_file = tmp_path / "bench.json"
    assert main(["bench", "--methods", "lbs,teacher", "--garments", "tshirt", "--vertices", "1000", "--frames", "3",
                 "--warmup", "1", "--checkpoint", str(tiny_checkpoint), "--device", "cpu", "--json", str(record_file),
                 "--quiet"]) == 0
    records = json.loads(record_file.read_text())
    assert [r["method"] for r in records] == ["lbs", "teacher"]
    for record in records:
        assert set(record) == {"method", "garment", "vertices", "device", "batch", "ms_per_frame", "p95_ms",
                               "from_frame", "stages"}
        assert 0 < record["ms_per_frame"] <= record["p95_ms"] and record["stages"] == {}
        assert record["device"] == "cpu" and record["garment"] == "tshirt"
    assert "| teacher | tshirt |" in capsys.readouterr().out


def test_missing_checkpoint_is_a_one_line_error(tmp_path, capsys):
    assert main(["simulate", "--method", "teacher", "--checkpoint", str(tmp_path / "none.pt"), "--garment", "tshirt",
                 "--vertices", "1000", "--frames", "2", "--out", str(tmp_path / "o"), "--no-preview", "--quiet"]) == 2
    assert "none.pt: checkpoint not found" in capsys.readouterr().err


def test_the_shipped_teacher_is_the_default_and_rolls_out(capsys):
    from hyperbones.models.loading import SHIPPED_TEACHER, load_checkpoint

    payload = load_checkpoint(SHIPPED_TEACHER)
    assert payload["step"] == payload["config"]["train"]["steps"] and "optimizer" not in payload
    summary = Path(__file__).resolve().parents[1] / "docs" / "checkpoints" / "teacher.md"
    assert f"Step {payload['step']}" in summary.read_text()  # the shipped teacher's export summary
    result = run_simulation("teacher", "tshirt", "walk", None, frames=4, vertices=1000, device="cpu")
    assert torch.isfinite(result.garment_vertices).all() and result.metrics["collision_pct"] < 5
