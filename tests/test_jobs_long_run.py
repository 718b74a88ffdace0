"""check long: the looping walk joins smoothly and is posed one stretch at a time; the table
reports every column, resident memory included (not a timing test)."""

import torch

from hyperbones.cli import main
from hyperbones.jobs.long_run import LoopedVertices, looped_walk


def test_looped_walk_repeats_one_stretch_smoothly(body):
    walk = looped_walk(body)
    assert walk.length >= 30 and walk.join_mm < 0.5 * walk.step_mm  # a whole number of gait cycles
    frames = walk.start + 3 * walk.length + 5
    posed = walk.posed(frames)
    # Only one stretch of the body is posed; each frame's vertices are made when asked for.
    assert isinstance(posed.vertices, LoopedVertices) and posed.vertices.shape == (frames, *body.rest_vertices.shape)
    assert walk.table.vertices.shape[0] == walk.start + walk.length and walk.repeats(frames) == 3

    joints = posed.joint_positions
    steps = (joints[1:] - joints[:-1]).norm(dim=-1).amax(dim=-1)  # (T-1,) m: the largest joint move per frame
    joins = [walk.start + k * walk.length - 1 for k in (1, 2, 3)]  # step from a stretch's end into the next
    stretch = steps[walk.start:walk.start + walk.length - 1]
    assert float(steps[joins].max()) <= 1.05 * float(stretch.max())
    # ...and a join's step is like its neighbours', not a jump.
    for join in joins:
        assert abs(float(steps[join]) - float(steps[join - 1])) < 0.25 * float(stretch.max())
    # Each repeat walks on: the hips are a stretch's distance further every stretch.
    assert torch.allclose(joints[walk.start + 2 * walk.length, 0], joints[walk.start, 0] + 2 * walk.advance, atol=1e-4)
    assert float(walk.advance.norm()) > 1.0

    # A frame of a later repeat is the body posed there, vertices included.
    t = walk.start + 2 * walk.length + 7
    direct = body.pose(posed.joint_rotations[t:t + 1], posed.joint_positions[t:t + 1, 0])
    assert torch.allclose(posed.vertices[t], direct.vertices[0], atol=1e-4)
    assert torch.allclose(posed.vertices[t:t + 1], direct.vertices, atol=1e-4)
    assert torch.allclose(posed.skinning_transforms[t], direct.skinning_transforms[0], atol=1e-4)


def test_check_long_prints_the_table(capsys):
    code = main(["check", "long", "--methods", "lbs,hyperbones", "--frames", "60", "--garment", "tshirt",
                 "--vertices", "1000", "--device", "cpu", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    header, rule, *rest = out.strip().splitlines()
    columns = [cell.strip() for cell in header.strip("|").split("|")]
    assert columns == ["method", "frames", "looped", "max speed m/s", "NaN/inf", "ms/frame median", "ms/frame p95",
                       "RSS MB @ early frame", "RSS MB @ last frame", "RSS growth MB"]
    rows = {cells[0]: cells for cells in ([c.strip() for c in line.strip("|").split("|")] for line in rest[:2])}
    assert set(rows) == {"lbs", "hyperbones"}
    for cells in rows.values():
        assert cells[1] == "60" and cells[2].startswith("no") and cells[4] == "0"
        assert 0.1 < float(cells[3]) < 20  # a walking garment moves, and not at runaway speed
        assert float(cells[5]) > 0 and float(cells[6]) >= float(cells[5])
        early, last = cells[7].split(), cells[8].split()
        assert float(early[0]) > 50 and early[1:] == ["(frame", "60)"] and float(last[0]) > 50
        assert abs(float(cells[9]) - (float(last[0]) - float(early[0]))) <= 1  # rounded MB
    assert "Looping walk: frames 0-" in out and "repeated" in out
