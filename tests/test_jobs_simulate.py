"""simulate --method lbs: the LBS baseline, metrics and the output contract, read back."""

import json

import numpy as np
import pytest
import torch
from pxr import Usd, UsdGeom

from conftest import cmu_clip
from hyperbones.cli import main
from hyperbones.export import read_frames_npz, read_pc2
from hyperbones.garment import TEMPLATES
from hyperbones.garment.draped import draped_garment
from hyperbones.rig.garment_skinning import LbsMethod
from hyperbones.jobs.simulate import run_simulation

METRIC_KEYS = {"edge_error_pct", "area_error_pct", "collision_pct", "collision_1mm_pct", "strain", "bending",
               "inertia", "gravity", "frames", "ms_per_frame", "ms_median", "ms_p95", "method", "garment", "motion",
               "body"}


def test_lbs_identity_pose_gives_the_drape(body):
    garment, _ = draped_garment("long-skirt", body, vertices=1500)
    method = LbsMethod(garment, body)
    assert torch.allclose(method.weights.sum(1), torch.ones(garment.num_vertices), atol=1e-5)
    posed = body.pose(torch.eye(3).repeat(2, 31, 1, 1), body.rest_root.repeat(2, 1))
    assert torch.allclose(method.run(posed)[1], garment.vertices, atol=1e-5)
    # Smoothed: neighbouring vertices have close weights (no tear between the legs); the
    # L1 norm counts a weight moving from one joint to another twice.
    edges = garment.edges()
    jump = (method.weights[edges[:, 0]] - method.weights[edges[:, 1]]).abs().sum(1)
    assert float(jump.max()) < 0.4


@pytest.mark.parametrize("motion", ["walk", "cmu"])
@pytest.mark.parametrize("garment", sorted(TEMPLATES))
def test_simulate_every_template(garment, motion):
    source = str(cmu_clip("02_01")) if motion == "cmu" else "walk"
    result = run_simulation("lbs", garment, source, None, frames=25, vertices=1000)
    assert result.garment_vertices.shape == (25, result.garment.num_vertices, 3)
    assert METRIC_KEYS <= set(result.metrics)
    assert 0 < result.metrics["ms_median"] <= result.metrics["ms_p95"]  # each frame timed on its own
    assert torch.isfinite(result.garment_vertices).all()
    assert 0 <= result.metrics["collision_pct"] < 20 and result.metrics["edge_error_pct"] < 40


def test_simulate_command_exports_read_back(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["simulate", "--garment", "tight-dress", "--vertices", "1500", "--motion", "walk", "--frames", "20",
                 "--out", str(out), "--quiet", "--obj"])
    assert code == 0
    frames = read_frames_npz(out / "frames.npz")
    garment = frames["garment_vertices"]
    assert garment.shape[0] == 20 and frames["body_vertices"].shape[0] == 20
    assert frames["joint_positions"].shape == (20, 31, 3) and frames["fps"] == 30.0
    pc2, start, rate = read_pc2(out / "garment.pc2")
    assert np.allclose(pc2, garment, atol=1e-6) and rate == 1.0
    stage = Usd.Stage.Open(str(out / "scene.usd"))
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and stage.GetTimeCodesPerSecond() == 30.0
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/garment"))
    assert np.allclose(np.array(mesh.GetPointsAttr().Get(7)), garment[7], atol=1e-6)
    metrics = json.loads((out / "metrics.json").read_text())
    assert METRIC_KEYS <= set(metrics) and metrics["frames"] == 20 and metrics["method"] == "hyperbones"
    assert (out / "preview.mp4").stat().st_size > 1000 and (out / "preview_sheet.png").exists()
    assert len(list((out / "obj").glob("garment_*.obj"))) == 20
    assert "ms/frame" in capsys.readouterr().out


def test_garment_make_command(tmp_path, capsys):
    from hyperbones.garment import load_obj_garment

    out = tmp_path / "skirt.obj"
    assert main(["garment", "make", "long-skirt", "--vertices", "1200", "--body", "weight=0.7", "--out", str(out)]) == 0
    garment = load_obj_garment(out)
    assert abs(garment.num_vertices - 1200) < 200 and len(garment.uvs) > 0
    assert "draped" in capsys.readouterr().out


def test_simulate_errors(tmp_path, capsys):
    assert main(["simulate", "--garment", "cape", "--out", str(tmp_path / "x")]) == 2
    assert "unknown garment 'cape'" in capsys.readouterr().err
    assert main(["simulate", "--garment", "missing.obj", "--out", str(tmp_path / "x")]) == 2
    assert "missing.obj: file not found" in capsys.readouterr().err
    assert main(["simulate", "--method", "magic", "--out", str(tmp_path / "x")]) == 2
    assert "unknown method 'magic'" in capsys.readouterr().err


def test_eval_writes_report(tmp_path, capsys):
    code = main(["eval", "--methods", "lbs", "--garments", "tight-dress,long-skirt", "--motions", "walk,jump",
                 "--frames", "15", "--vertices", "1500", "--out", str(tmp_path), "--quiet"])
    assert code == 0
    runs = json.loads((tmp_path / "report.json").read_text())
    assert len(runs) == 4 and {r["motion"] for r in runs} == {"walk", "jump"}
    table = (tmp_path / "report.md").read_text()
    assert "| tight-dress | lbs |" in table and "| long-skirt | lbs |" in table and "ε_e" in table
