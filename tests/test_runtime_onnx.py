"""The per-frame runtime exported to ONNX: onnxruntime against the torch runtime (no contact)
over 300 frames of walk, the command's files and its contract, the bench method."""

from __future__ import annotations

import json

import numpy as np
import onnxruntime
import pytest
import torch

from hyperbones.body.anny_body import body_for
from hyperbones.body.shape import BodyShape
from hyperbones.cli import main
from hyperbones.garment.draped import draped_garment
from hyperbones.jobs.export_onnx import runtime_frame
from hyperbones.motion.load import load_motion
from hyperbones.runtime.onnx_frame import INPUTS, ONNX_OVERRIDES, OUTPUTS, write_onnx
from hyperbones.runtime.simulator import Simulator


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    frame, draped = runtime_frame("tshirt", vertices=1500)
    path = write_onnx(frame, tmp_path_factory.mktemp("onnx") / "runtime.onnx")
    return frame, draped, onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_onnx_matches_the_torch_runtime_over_300_frames_of_walk(exported):
    frame, draped, session = exported
    body = body_for(BodyShape())
    motion = load_motion("walk", body)
    motion = motion.with_hold(300 - motion.num_frames).slice(0, 300)
    posed = body.pose(motion.joint_rotations, motion.root_translation)
    garment, rest = draped_garment("tshirt", body, vertices=1500)
    simulator = Simulator.load([(garment, body)], overrides=ONNX_OVERRIDES, rest_vertices=[rest])
    rotations, roots = posed.joint_rotations.float(), posed.joint_positions[:, 0].float()
    state = [value.numpy() for value in frame.initial_state().values()]
    differences = []
    for t in range(300):
        expected = simulator.step(rotations[t:t + 1], roots[t:t + 1])[0].numpy()
        outputs = session.run(None, dict(zip(INPUTS, [rotations[t].numpy(), roots[t].numpy(), *state])))
        differences.append(np.abs(outputs[0] - expected).max())
        state = outputs[1:]
    assert max(differences) <= 1e-4  # 0.1 mm
    assert np.ptp(outputs[0][:, 2]) > 0.3  # a garment, not a point


def test_export_onnx_command_writes_the_graph_its_contract_and_mesh(tmp_path, capsys):
    out = tmp_path / "engine"
    assert main(["export-onnx", "--garment", "tshirt", "--vertices", "1000", "--out", str(out)]) == 0
    assert "runtime.onnx" in capsys.readouterr().out
    assert sorted(path.name for path in out.iterdir()) == ["contract.json", "garment.obj", "runtime.onnx"]
    contract = json.loads((out / "contract.json").read_text())
    session = onnxruntime.InferenceSession(str(out / "runtime.onnx"), providers=["CPUExecutionProvider"])
    assert [node.name for node in session.get_inputs()] == list(contract["inputs"]) == list(INPUTS)
    assert [node.name for node in session.get_outputs()] == list(OUTPUTS)
    for node in session.get_inputs():
        assert list(node.shape) == contract["inputs"][node.name]["shape"]
    for node in session.get_outputs():
        assert list(node.shape) == contract["outputs"][node.name]["shape"]
    vertex_lines = [line for line in (out / "garment.obj").read_text().splitlines() if line.startswith("v ")]
    assert len(vertex_lines) == contract["garment"]["vertices"] == session.get_outputs()[0].shape[0]
    assert contract["runtime"]["contact"] is False


def test_export_onnx_refuses_a_missing_garment_in_one_line(tmp_path, capsys):
    assert main(["export-onnx", "--garment", "missing.obj", "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == "hyperbones: error: missing.obj: file not found"
    assert not (tmp_path / "x").exists()


def test_bench_times_the_onnx_method():
    from hyperbones.jobs.bench import bench

    records = bench(["hyperbones-onnx"], ["tshirt"], vertices=1000, frames=3, warmup=1, device="cpu",
                    progress=False)
    assert records[0].method == "hyperbones-onnx" and records[0].ms_per_frame > 0
    assert torch.isfinite(torch.tensor(records[0].p95_ms))
