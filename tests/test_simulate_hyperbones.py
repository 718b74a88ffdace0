"""simulate/bench --method hyperbones with a (tiny, briefly trained) joint checkpoint."""

import json

import pytest
import torch

from hyperbones.cli import main
from hyperbones.simulate.pipeline import run_simulation
from hyperbones.training.config import HyperBonesTrainingConfig
from hyperbones.training.joint import JointTrainer
from test_training_joint import TINY_JOINT


@pytest.fixture(scope="module")
def joint_checkpoint(tmp_path_factory, body):
    run = tmp_path_factory.mktemp("joint") / "run"
    trainer = JointTrainer(HyperBonesTrainingConfig.from_dict(TINY_JOINT), run, progress=False, max_steps=1)
    trainer.train()
    trainer.close()
    return run / "checkpoint.pt"


def test_hyperbones_and_its_teacher_simulate(joint_checkpoint):
    result = run_simulation("hyperbones", "tshirt", "walk", vertices=1000, frames=30, checkpoint=str(joint_checkpoint),
                            device="cpu")
    assert result.garment_vertices.shape == (30, result.garment.num_vertices, 3)
    assert torch.isfinite(result.garment_vertices).all() and result.metrics["method"] == "hyperbones"
    # Barely trained, it is about skinning by the virtual bones: it follows the walking body
    # as LBS does.
    lbs = run_simulation("lbs", "tshirt", "walk", vertices=1000, frames=30)
    assert float((result.garment_vertices[-1] - result.garment_vertices[0]).norm(dim=1).mean()) > 0.02
    assert float((result.garment_vertices - lbs.garment_vertices).norm(dim=-1).mean()) < 0.02
    teacher = run_simulation("teacher", "tshirt", "walk", vertices=1000, frames=3, checkpoint=str(joint_checkpoint),
                             device="cpu")
    assert torch.isfinite(teacher.garment_vertices).all()


def test_bench_reports_the_speedup(joint_checkpoint, tmp_path, capsys):
    record_file = tmp_path / "bench.json"
    assert main(["bench", "--methods", "teacher,hyperbones", "--garments", "tshirt", "--vertices", "1000",
                 "--frames", "3", "--warmup", "1", "--checkpoint", str(joint_checkpoint), "--device", "cpu",
                 "--uv-resolution", "32", "--json", str(record_file), "--quiet"]) == 0
    records = json.loads(record_file.read_text())
    assert [r["method"] for r in records] == ["teacher", "hyperbones"]
    out = capsys.readouterr().out
    assert "| hyperbones | tshirt |" in out and "hyperbones is " in out and "faster than the teacher on tshirt" in out
