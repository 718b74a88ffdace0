"""The command line: output contracts, one-line errors, render and demo."""

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from conftest import cmu_clip
from hyperbones.body.skeleton import JOINT_NAMES, LIMB_SEGMENTS
from hyperbones.cli import main


def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_motion_builtin_npz_contract(tmp_path, capsys):
    out = tmp_path / "walk.npz"
    code, stdout, _ = _run(capsys, "motion", "walk", "--duration", "2", "--body", "weight=0.8", "--out", str(out))
    assert code == 0 and "wrote" in stdout
    data = np.load(out)
    assert list(data["joint_names"]) == list(JOINT_NAMES)
    frames = data["joint_positions"].shape[0]
    assert frames == 61 + 15  # 2 s at 30 fps plus the default 15-frame blend-in
    assert data["joint_positions"].shape == (frames, 31, 3)
    rot = torch.as_tensor(data["joint_rotations"])
    assert rot.shape == (frames, 31, 3, 3)
    assert torch.allclose(rot @ rot.transpose(-1, -2), torch.eye(3).expand_as(rot), atol=1e-4)
    assert float(data["fps"]) == 30.0
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary file left behind


def test_motion_bvh_frame_i_is_time_i_over_fps(tmp_path, capsys):
    from test_motion_retarget import _angles, _reference_positions

    path = cmu_clip("16_35")
    out = tmp_path / "run.npz"
    assert _run(capsys, "motion", str(path), "--blend-in", "0", "--out", str(out))[0] == 0
    positions = torch.as_tensor(np.load(out)["joint_positions"])
    reference = _reference_positions(path, len(positions), None)
    for arm in ("left forearm", "right upper arm"):
        assert _angles(positions, reference, LIMB_SEGMENTS[arm]).max() < 0.05


CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("argv, phrase", [
    (["motion", "walk", "--body", "foo=1", "--out", "x.npz"], "--body: unknown key 'foo'"),
    (["motion", "walk", "--body", "weight=2", "--out", "x.npz"], "out of range"),
    (["motion", "moonwalk", "--out", "x.npz"], "unknown motion 'moonwalk'"),
    (["motion", "walk", "--out", "x.txt"], "must end in .npz"),
    (["motion", "walk", "--blend-in", "-3", "--out", "x.npz"], "--blend-in"),
    (["motion", "walk"], "--out FILE.npz is required"),
    (["motion", "missing.bvh", "--out", "x.npz"], "missing.bvh: file not found"),
    (["check", "drape", "--templates", "tshirt,cape"], "unknown template(s) ['cape']"),
    (["check", "drape", "--resolutions", "2500,lots"], "--resolutions must be a comma list"),
    (["check", "drape", "--bodies", "weight=0.2;hight=1"], "unknown key 'hight'"),
    (["train", "--config", str(CONFIGS / "teacher-small.toml"), "--set", "train.stepz=3", "--out", "run"],
     "--set train.stepz=3: unknown key 'stepz'"),
    (["train", "--config", str(CONFIGS / "teacher-small.toml"), "--set", "train.steps=many", "--out", "run"],
     "train.steps must be int"),
    (["simulate", "--runtime", "follow=2", "--out", "run"], "--runtime: runtime follow=2.0 must be in (0, 1]"),
    (["eval", "--split", "validation", "--motions", "walk", "--out", "run"], "--split sets the motions and bodies"),
])
def test_errors_are_one_line(tmp_path, capsys, monkeypatch, argv, phrase):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, *argv)
    assert code == 2
    assert err.startswith("hyperbones: error:") and phrase in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_check_drape_prints_a_row_per_drape(capsys):
    code, out, _ = _run(capsys, "check", "drape", "--templates", "tshirt", "--resolutions", "1000", "--bodies",
                        "weight=0.7", "--quiet")
    header, rule, *rows = out.strip().splitlines()
    assert code == 0 and header.startswith("| garment | vertices | body |") and rule.startswith("|---|")
    assert len(rows) == 2  # the default body first: the strain reference
    default, heavier = ([cell.strip() for cell in row.strip("|").split("|")] for row in rows)
    assert default[0] == heavier[0] == "tshirt" and default[2] == "default" and heavier[2] == "weight=0.7"
    assert float(heavier[4]) == 0.0 and float(heavier[5]) < 3.0  # collision % after, edge error %
    assert float(default[8]) == float(default[9]) == float(default[10]) == 1.0  # the default body is the reference
    area, strain, scaled = float(heavier[8]), float(heavier[9]), float(heavier[10].rstrip(" ✗"))
    assert area > 1.0  # a heavier body's tshirt is larger
    assert abs(strain - float(heavier[7]) / float(default[7])) < 0.02 * strain
    assert abs(scaled - strain / area**2) < 0.02 * scaled


def test_malformed_bvh_names_the_file(tmp_path, capsys):
    bad = tmp_path / "broken.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    code, _, err = _run(capsys, "motion", str(bad), "--out", str(tmp_path / "x.npz"))
    assert code == 2 and "broken.bvh" in err and err.count("\n") == 1


def test_render_writes_video_and_sheet(tmp_path, capsys):
    out = tmp_path / "idle.mp4"
    code, stdout, _ = _run(capsys, "render", "idle", "--duration", "1", "--blend-in", "0", "--size", "128",
                           "--quiet", "--out", str(out))
    assert code == 0
    frames = iio.imread(out)
    assert frames.shape[0] == 31 and frames.shape[1:3] == (128, 128)
    assert (tmp_path / "idle_sheet.png").exists()
    # The body is drawn: frames are not just background.
    assert frames[0].std() > 10


def test_demo_and_console_script(tmp_path):
    """The README's main job, through the installed console script: the shipped model moves
    the dress with the walking body."""
    exe = Path(sys.executable).with_name("hyperbones")
    result = subprocess.run([str(exe), "demo", "--quiet", "--device", "cpu", "--out", str(tmp_path / "demo")],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    for name in ("preview.mp4", "preview_sheet.png", "frames.npz", "garment.pc2", "scene.usd", "metrics.json"):
        assert (tmp_path / "demo" / name).stat().st_size > 100
    assert "preview.mp4" in result.stdout
    metrics = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    assert metrics["method"] == "hyperbones" and metrics["garment"] == "dress"
    assert metrics["edge_error_pct"] < 5.0 and metrics["collision_pct"] < 0.5
    frames = np.load(tmp_path / "demo" / "frames.npz")
    garment, root = frames["garment_vertices"].mean(axis=1), frames["joint_positions"][:, 0]
    assert np.linalg.norm(root[-1] - root[0]) > 1.0  # the body walks a metre or more...
    assert np.linalg.norm(garment - root, axis=1).max() < 0.4  # ...and the dress goes with it


def test_help_explains_commands(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for verb in ("demo", "simulate", "eval", "bench", "motion", "render", "train", "check"):
        assert verb in out
    with pytest.raises(SystemExit):
        main(["check", "--help"])
    out = capsys.readouterr().out
    for check in ("retarget", "builtins", "drape", "teacher", "hem"):
        assert check in out


def test_help_takes_choices_and_defaults_from_the_code(capsys):
    """The verbs' help lists the methods and templates the code has, and its defaults."""
    from hyperbones.garment.templates import DEFAULT_VERTICES, TEMPLATES
    from hyperbones.jobs.methods import METHODS
    from hyperbones.motion.load import DEFAULT_BLEND_IN

    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert all(name in out for name in METHODS) and all(name in out for name in TEMPLATES)
    assert f"(default: {DEFAULT_VERTICES})" in out and f"(default: {DEFAULT_BLEND_IN})" in out
    assert "--runtime" in out and "--uv-resolution" in out
