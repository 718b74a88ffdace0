"""bench: percentiles, --profile's stage tables and --batch's crowds (on drapes other tests make:
the 1,000-vertex tshirt and dress on the default body)."""

import json

import pytest
import torch

from hyperbones.cli import main
from hyperbones.jobs.timing import BenchRecord, stage_table, timed_blocks


def test_timed_blocks_prepare_off_the_clock_and_wrap_each_block():
    """prepare(t) comes before every step(t); around(i) encloses exactly block i's timed frames."""
    events = []

    class Around:
        def __init__(self, index):
            self.index = index

        def __enter__(self):
            events.append(("enter", self.index))

        def __exit__(self, *exc):
            events.append(("exit", self.index))

    blocks = timed_blocks(lambda t: events.append(("step", t)), torch.device("cpu"), warmup=1, frames=2, late=4,
                          prepare=lambda t: events.append(("prepare", t)), around=Around)
    steps = [("prepare", 0), ("step", 0)]
    assert events == steps + [("enter", 0), ("prepare", 1), ("step", 1), ("prepare", 2), ("step", 2), ("exit", 0),
                              ("prepare", 3), ("step", 3),
                              ("enter", 1), ("prepare", 4), ("step", 4), ("prepare", 5), ("step", 5), ("exit", 1)]
    assert [block.first for block in blocks] == [1, 4]
    assert all(0 <= block.median <= block.p95 for block in blocks)


def test_stage_table_lists_the_stages_their_total_and_the_frame():
    record = BenchRecord("hyperbones", "dress", 1054, "cpu", 1, 10.0, 12.0, 5,
                         {"Bone-Net": 2.0, "Conv-MLP": 5.0, "projection": 1.5})
    rows = stage_table(record).splitlines()
    assert rows[0].startswith("hyperbones on dress (1054 vertices, cpu, batch 1)")
    assert rows[1] == "| stage | ms/frame | share of the frame (%) |"
    assert rows[3:] == ["| Bone-Net | 2.000 | 20.0 |", "| Conv-MLP | 5.000 | 50.0 |", "| projection | 1.500 | 15.0 |",
                        "| total of the stages | 8.500 | 85.0 |", "| frame (median) | 10.000 | 100.0 |"]
    crowd = BenchRecord("hyperbones", "crowd of 8 (dress)", 1054, "cpu", 8, 4.0, 5.0, 5, {"Conv-MLP": 1.0})
    assert "| stage | ms/character-frame | share of the frame (%) |" in stage_table(crowd)


def _stage_rows(out: str, title: str) -> dict[str, float]:
    """{row name: ms} of the stage table printed under the line starting with ``title``."""
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(title))
    rows = {}
    for line in lines[start + 3:]:
        if not line.startswith("| "):
            break
        name, ms, _ = (cell.strip() for cell in line.strip("|").split("|"))
        rows[name] = float(ms)
    return rows


def test_profile_prints_and_records_the_runtime_stages(tmp_path, capsys):
    from hyperbones.runtime.stage_clock import STAGES

    record_file = tmp_path / "bench.json"
    assert main(["bench", "--methods", "lbs,hyperbones", "--garments", "dress", "--vertices", "1000", "--frames", "4",
                 "--warmup", "2", "--late", "8", "--device", "cpu", "--profile", "--json", str(record_file),
                 "--quiet"]) == 0
    records = json.loads(record_file.read_text())
    assert [(r["method"], r["from_frame"]) for r in records] == [("lbs", 2), ("lbs", 8), ("hyperbones", 2),
                                                                 ("hyperbones", 8)]
    for record in records:
        assert 0 < record["ms_per_frame"] <= record["p95_ms"]
    lbs, _, profiled, late = records
    assert lbs["stages"] == {} and late["stages"] == {}  # no runtime; the late block is not profiled
    stages = profiled["stages"]
    # The runtime's own stages, in the order a frame runs them, each charged something.
    assert list(stages) == [name for name in STAGES if name in stages]
    assert {"forward kinematics", "Bone-Net", "garment skinning", "contact queries", "projection"} <= set(stages)
    assert all(ms > 0 for ms in stages.values())
    # A consistency check, not a speed one: the stages make up most of a frame and no more than
    # it. Their sum is a mean over the frames, so a loaded machine's slow frames pull it above
    # the median: at most to the slowest frame, which the 95th percentile of 4 is near.
    assert 0.3 * profiled["ms_per_frame"] < sum(stages.values()) < 1.5 * profiled["p95_ms"]

    out = capsys.readouterr().out
    assert "| ms/frame (median) | p95 |" in out
    rows = _stage_rows(out, "hyperbones on dress (")
    assert list(rows) == [*stages, "total of the stages", "frame (median)"]
    assert all(rows[name] == pytest.approx(ms, abs=1e-3) for name, ms in stages.items())
    assert rows["total of the stages"] == pytest.approx(sum(stages.values()), abs=2e-3)
    assert rows["frame (median)"] == pytest.approx(profiled["ms_per_frame"], abs=1e-3)
    assert "lbs on dress (" not in out and "(--profile: no stage table for lbs," in out


def test_crowd_characters_differ_until_the_pairs_run_out():
    from hyperbones.body.shape import BodyShape
    from hyperbones.jobs.bench import CROWD_BODIES, crowd_characters

    characters = crowd_characters(["dress", "tshirt"], 9, 4)
    assert len(set(characters[:8])) == 8 and characters[8] == characters[0]
    assert characters[:3] == [("dress", 0), ("tshirt", 0), ("dress", 1)]
    assert crowd_characters(["dress"], 3, 4) == [("dress", 0), ("dress", 1), ("dress", 2)]
    shapes = [BodyShape.parse(text) for text in CROWD_BODIES]
    assert shapes[0] == BodyShape() and len(set(shapes)) == len(shapes) <= 4


def test_help_states_the_crowds_methods_and_bodies(capsys):
    from hyperbones.jobs.bench import CROWD_BODIES, CROWD_METHODS

    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert f"({' and '.join(CROWD_METHODS)} only)" in out and f"--garments and {len(CROWD_BODIES)} body shapes" in out
    assert "--profile" in out and "p95_ms" in out


def test_a_crowd_steps_its_characters_together(tmp_path, monkeypatch):
    """--batch 5 over two garments and (here) two bodies: one Simulator steps five characters,
    each distinct garment x body encoded once; the record is per character-frame."""
    from hyperbones.jobs import bench
    from hyperbones.runtime import identity
    from hyperbones.runtime.simulator import Simulator

    # Two copies of the default body: the crowd's path over several bodies, on drapes other tests share.
    monkeypatch.setattr(bench, "CROWD_BODIES", ("default", "default"))
    encoded, frames = [], []
    encode, step = identity.encode_identity, Simulator.step
    monkeypatch.setattr(identity, "encode_identity",
                        lambda *args, **kwargs: encoded.append(1) or encode(*args, **kwargs))
    monkeypatch.setattr(Simulator, "step", lambda self, *args: frames.append(step(self, *args)) or frames[-1])
    record_file = tmp_path / "crowd.json"
    assert main(["bench", "--methods", "hyperbones", "--garments", "tshirt,dress", "--vertices", "1000",
                 "--frames", "2", "--warmup", "1", "--device", "cpu", "--batch", "5", "--profile",
                 "--json", str(record_file), "--quiet"]) == 0
    (record,) = json.loads(record_file.read_text())
    assert record["method"] == "hyperbones" and record["batch"] == 5
    assert record["garment"] == "crowd of 5 (tshirt,dress on 2 bodies)"
    assert 0 < record["ms_per_frame"] <= record["p95_ms"] and record["stages"]
    assert 0.3 * record["ms_per_frame"] < sum(record["stages"].values()) < 1.5 * record["p95_ms"]
    assert len(encoded) == 4  # (tshirt, dress) x 2 bodies; the fifth character is the first again
    assert len(frames) == 3 and all(len(frame) == 5 for frame in frames)
    tshirt, dress = frames[0][0].shape[0], frames[0][1].shape[0]
    assert tshirt != dress and [v.shape[0] for v in frames[0]] == [tshirt, dress, tshirt, dress, tshirt]
    assert record["vertices"] == round((3 * tshirt + 2 * dress) / 5)
    # Characters 0 and 4 wear one garment on one body and move alike (to float rounding, which
    # differs with a character's place in the batch and which the contact step can turn into a
    # millimetre on the few vertices whose nearest body face is a near tie).
    for frame in frames:
        assert float((frame[0] - frame[4]).norm(dim=1).mean()) < 1e-4


@pytest.mark.parametrize(("options", "message"), [
    (["--methods", "lbs,hyperbones", "--batch", "2"],
     "--batch 2 steps characters together in one Simulator, which only hyperbones and hyperbones-raw have; "
     "drop lbs or use --batch 1"),
    (["--methods", "hyperbones", "--batch", "0"], "--batch must be >= 1, got 0"),
    (["--methods", "hyperbones", "--garments", ","], "--garments names no garment"),
])
def test_bad_bench_options_are_one_line_errors(options, message, capsys):
    assert main(["bench", *options, "--vertices", "1000", "--device", "cpu", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
