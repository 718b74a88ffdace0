"""simulate/bench --method hyperbones with a (tiny, briefly trained) joint checkpoint."""

import json

import pytest
import torch

from hyperbones.cli import main
from hyperbones.jobs.simulate import run_simulation
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
    # Without the contact step, the skinned tshirt sinks into the body in places; with it, none does.
    raw = run_simulation("hyperbones-raw", "tshirt", "walk", vertices=1000, frames=30,
                         checkpoint=str(joint_checkpoint), device="cpu")
    assert raw.metrics["method"] == "hyperbones-raw" and raw.metrics["collision_pct"] > 1.0
    assert result.metrics["collision_pct"] < 0.05 * raw.metrics["collision_pct"]
    # Strain limiting after contact: the edges are nearer their rest lengths than Module A left them.
    assert result.metrics["edge_error_pct"] < raw.metrics["edge_error_pct"]


def test_bench_reports_the_speedup(joint_checkpoint, tmp_path, capsys):
    record_file = tmp_path / "bench.json"
    assert main(["bench", "--methods", "teacher,hyperbones", "--garments", "tshirt", "--vertices", "1000",
                 "--frames", "3", "--warmup", "1", "--late", "6", "--checkpoint", str(joint_checkpoint),
                 "--device", "cpu", "--uv-resolution", "32", "--json", str(record_file), "--quiet"]) == 0
    records = json.loads(record_file.read_text())
    assert [(r["method"], r["from_frame"]) for r in records] == [("teacher", 1), ("teacher", 6), ("hyperbones", 1),
                                                                 ("hyperbones", 6)]
    out = capsys.readouterr().out
    assert "| hyperbones | tshirt |" in out and "hyperbones is " in out and "faster than the teacher on tshirt" in out


def test_simulator_load_and_module_a_alone(joint_checkpoint, body):
    """The Python API: Simulator.load on (garment, body) pairs; load_module_a for Module A alone."""
    from hyperbones.garment.templates import make_template
    from hyperbones.motion.builtin import builtin_motion
    from hyperbones.models.loading import load_module_a
    from hyperbones.runtime.simulator import Simulator

    garment = make_template("tshirt", body, vertices=1000)
    simulator = Simulator.load([(garment, body), (garment, body)], joint_checkpoint)
    motion = builtin_motion("walk", body, duration=0.5)
    for t in range(motion.num_frames):
        first, second = simulator.step(motion.joint_rotations[t].expand(2, 31, 3, 3),
                                       motion.root_translation[t].expand(2, 3))
    assert first.shape == (garment.num_vertices, 3) and torch.allclose(first, second)
    module_a = load_module_a(joint_checkpoint)  # float32; the simulator may run the Conv-MLP in bfloat16
    assert all(torch.equal(a.to(b.dtype), b) for a, b in zip(module_a.state_dict().values(),
                                                              simulator.module_a.state_dict().values()))


def test_the_conv_mlp_runs_in_bfloat16_only_where_the_device_has_it(joint_checkpoint, body, monkeypatch):
    """``RuntimeConfig.bfloat16`` (the shipped model's setting) is honoured where bfloat16 is
    native; on a CPU that would emulate it (several times slower than float32) the Conv-MLP runs
    in float32, and the run's metrics say which dtype ran."""
    import hyperbones.runtime.simulator as simulator_module
    from hyperbones.garment.templates import make_template
    from hyperbones.runtime.simulator import Simulator

    garment = make_template("tshirt", body, vertices=1000)
    for native, bfloat16, expected in ((True, True, torch.bfloat16), (False, True, torch.float32),
                                       (True, False, torch.float32)):
        monkeypatch.setattr(simulator_module, "runs_bfloat16_natively", lambda device, native=native: native)
        simulator = Simulator.load([(garment, body)], joint_checkpoint, overrides={"bfloat16": bfloat16})
        assert simulator.config.bfloat16 is bfloat16  # the setting is kept as asked; the dtype is the device's
        assert simulator.conv_mlp_dtype == expected
        assert {p.dtype for p in simulator.module_a.refiner.parameters()} == {expected}
    monkeypatch.undo()
    raw = run_simulation("hyperbones-raw", "tshirt", "walk", vertices=1000, frames=2, checkpoint=str(joint_checkpoint),
                         device="cpu")
    ran = "bfloat16" if simulator_module.runs_bfloat16_natively(torch.device("cpu")) else "float32"
    assert raw.metrics["conv_mlp_dtype"] == (ran if raw.metrics["runtime"]["bfloat16"] else "float32")
    assert run_simulation("lbs", "tshirt", "walk", vertices=1000, frames=2).metrics["conv_mlp_dtype"] is None


def test_eval_takes_the_uv_resolution(joint_checkpoint, tmp_path, monkeypatch):
    """--uv-resolution reaches the UV maps Module A runs on (the checkpoint was trained at
    R = 16; without the option the maps take the runtime settings', which for a training
    checkpoint are the shipped model's)."""
    from hyperbones.geometry.uv_raster import UvRaster
    from hyperbones.runtime.simulator import shipped_runtime_config

    built = []
    build = UvRaster.build

    def recording_build(cls, *args, **kwargs):
        raster = build(*args, **kwargs)
        built.append(raster.resolution)
        return raster

    monkeypatch.setattr(UvRaster, "build", classmethod(recording_build))
    out = tmp_path / "eval"
    assert main(["eval", "--methods", "lbs,hyperbones-raw", "--garments", "tshirt", "--motions", "walk",
                 "--frames", "4", "--vertices", "1000", "--uv-resolution", "40", "--checkpoint", str(joint_checkpoint),
                 "--device", "cpu", "--out", str(out), "--quiet"]) == 0
    methods = [run["method"] for run in json.loads((out / "report.json").read_text())]
    assert methods == ["lbs", "hyperbones-raw"]
    assert built == [40]  # one identity's maps, for hyperbones-raw alone, at the resolution asked for
    run_simulation("hyperbones-raw", "tshirt", "walk", vertices=1000, frames=2, checkpoint=str(joint_checkpoint),
                   device="cpu")
    assert built[1:] == [shipped_runtime_config().uv_resolution or 16] and built[1] != 40


def test_the_shipped_model_loads_safely_and_beats_lbs_on_a_walk():
    """The package's trained model: small enough to ship, loadable without pickled code, the
    default of --method hyperbones, and better than skinning where the issue asks it to be."""
    from hyperbones.models.loading import hyperbones_payload, load_module_a
    from hyperbones.models.loading import SHIPPED_HYPERBONES, load_checkpoint

    shipped = sum(path.stat().st_size for path in SHIPPED_HYPERBONES.parent.glob("*.pt"))
    assert shipped < 30e6
    payload = load_checkpoint(SHIPPED_HYPERBONES)  # torch.load(weights_only=True)
    assert payload["step"] > 0 and set(payload) == {"model", "config", "step", "runtime_config"}
    assert hyperbones_payload()["config"]["runtime"]["num_bones"] == payload["config"]["runtime"]["num_bones"]
    assert not load_module_a().training
    ours = run_simulation("hyperbones", "dress", "walk", vertices=1500, frames=90, device="cpu")
    lbs = run_simulation("lbs", "dress", "walk", vertices=1500, frames=90)
    for metric in ("edge_error_pct", "area_error_pct", "collision_pct"):
        assert ours.metrics[metric] < 0.5 * lbs.metrics[metric], metric
    assert ours.metrics["inertia"] < lbs.metrics["inertia"]
