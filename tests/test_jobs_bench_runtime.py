"""bench-runtime: the per-frame runtime timed on saved identity caches and a motion .npz."""

import json

import numpy as np
import pytest
import torch

from hyperbones.cli import main
from hyperbones.errors import InputFileError
from hyperbones.models.hyperbones import HyperBonesModel
from hyperbones.jobs.bench_runtime import load_motion_npz
from hyperbones.runtime.identity import encode_identity
from test_runtime_identity import SMALL


def test_bench_runtime_command(tmp_path, body, capsys):
    from hyperbones.garment.templates import make_template

    torch.manual_seed(0)
    with torch.no_grad():
        identity = encode_identity(HyperBonesModel(SMALL), make_template("dress", body, vertices=1500), body)
    cache = identity.save(tmp_path / "dress.pt")
    motion = tmp_path / "walk.npz"
    assert main(["motion", "walk", "--out", str(motion)]) == 0
    rotations, roots = load_motion_npz(motion)
    assert rotations.shape[1:] == (31, 3, 3) and roots.shape == (rotations.shape[0], 3)
    out = tmp_path / "rt.json"
    late = rotations.shape[0] + 5  # past the motion's end: the pose is held
    assert main(["bench-runtime", "--identity", str(cache), "--motion", str(motion), "--uv-resolution", "16",
                 "--batch", "2", "--frames", "3", "--warmup", "1", "--late", str(late), "--json", str(out)]) == 0
    record, later = json.loads(out.read_text())
    assert record["method"] == "hyperbones@16" and record["batch"] == 2 and record["ms_per_frame"] > 0
    assert (record["from_frame"], later["from_frame"]) == (1, late) and later["ms_per_frame"] > 0
    assert all(r["p95_ms"] >= r["ms_per_frame"] and r["stages"] == {} for r in (record, later))
    assert record["vertices"] == identity.num_vertices and record["garment"] == "dress"
    assert "timing only" in capsys.readouterr().out


def test_identity_command_writes_a_cache(tmp_path, capsys):
    from hyperbones.runtime.identity import Identity

    out = tmp_path / "tshirt.pt"
    assert main(["identity", "--garment", "tshirt", "--vertices", "1000", "--untrained", "--uv-resolution", "32",
                 "--out", str(out)]) == 0
    assert "untrained: for timing only" in capsys.readouterr().out
    identity = Identity.load(out)
    assert identity.raster.resolution == 32 and identity.bones.num_bones == 128
    assert main(["identity", "--untrained", "--checkpoint", "x.pt", "--out", str(out)]) == 2


def test_bad_motion_file(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, something=np.zeros(3))
    with pytest.raises(InputFileError, match="bad.npz: not a hyperbones motion .npz"):
        load_motion_npz(bad)
    with pytest.raises(InputFileError, match="motion file not found"):
        load_motion_npz(tmp_path / "none.npz")


def test_timed_blocks_time_the_frames_asked_for():
    from hyperbones.errors import ParameterError
    from hyperbones.jobs.timing import timed_blocks

    seen = []
    blocks = timed_blocks(seen.append, torch.device("cpu"), warmup=2, frames=3, late=10)
    assert seen == list(range(13)) and [block.first for block in blocks] == [2, 10]
    assert all(0 <= block.median <= block.p95 for block in blocks)
    with pytest.raises(ParameterError, match="--late 3 must come after the first timed block"):
        timed_blocks(seen.append, torch.device("cpu"), warmup=2, frames=3, late=3)

