"""The training pack and the torch-only trainer, on a tiny pack (two bodies, one 1k-vertex
template, one CMU clip and the built-in walk): the pack rebuilds Anny's bodies, and phase 1
and phase 2 train, resume and keep finite losses where importing anny, warp, numba or
potpourri3d fails; Module A overfits one fixed batch of teacher frames."""

from __future__ import annotations

import json
import os
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from hyperbones.body.anny_body import Body
from hyperbones.body.shape import BodyShape
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.training.config import apply_overrides, load_config
from hyperbones.training.pack import build_pack
from hyperbones.training.pack_data import PackData, TrainingPack

from conftest import CMU_DIR, cmu_clip

ROOT = Path(__file__).resolve().parents[1]

TINY_DATA = """
[data]
templates = ["tshirt"]
resolutions = [1000]
mocap_dir = "{mocap}"
train_clips = ["01_01"]
validation_clips = ["01_01"]
builtins = ["walk"]
"""

TEACHER = """
[model]
latent = 16
blocks = 2

[train]
steps = 6
checkpoint_every = 100
log_every = 1
rollout_start = 2
rollout_max = 2
collision_ramp_steps = 0
""" + TINY_DATA

JOINT = """
[model]
latent = 16
blocks = 2

[runtime]
uv_resolution = 16
window_frames = 4
num_bones = 32

[joint]
train_teacher = false
frames_per_step = 2
cache_size = 2
rollout_frames = 6
refresh_every = 2
max_detached_pct = 50.0

[train]
steps = 4
checkpoint_every = 100
log_every = 1
collision_ramp_steps = 0
""" + TINY_DATA

BLOCKED = textwrap.dedent("""
    import sys
    for name in ("anny", "warp", "numba", "potpourri3d"):
        sys.modules[name] = None  # importing any of them now raises ImportError
    from hyperbones.training.from_pack import main
    code = main(sys.argv[1:])
    print("loaded:", sorted(n for n in ("anny", "warp", "numba", "potpourri3d") if sys.modules.get(n) is not None))
    sys.exit(code)
""")


@pytest.fixture(scope="module")
def packs(tmp_path_factory):
    """(folder, teacher config, teacher pack, joint config, joint pack)."""
    cmu_clip("01_01")
    folder = tmp_path_factory.mktemp("packs")
    teacher_config = folder / "teacher.toml"
    teacher_config.write_text(TEACHER.format(mocap=CMU_DIR))
    joint_config = folder / "joint.toml"
    joint_config.write_text(JOINT.format(mocap=CMU_DIR))  # C: a small random teacher, frozen
    build_pack(load_config(teacher_config), folder / "teacher.pt", bodies=2)
    build_pack(load_config(joint_config), folder / "joint.pt", bodies=2)
    return folder, teacher_config, folder / "teacher.pt", joint_config, folder / "joint.pt"


def train_blocked(*args: str) -> dict:
    """Run the pack trainer in a subprocess without Anny, Warp, numba and potpourri3d; its JSON summary."""
    done = subprocess.run([sys.executable, "-c", BLOCKED, *map(str, args), "--device", "cpu", "--quiet"],
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "loaded: []" in done.stdout
    return json.loads(done.stdout.strip().splitlines()[-2])


def logged(run: Path) -> dict[str, list[tuple[int, float]]]:
    from hyperbones.training.summary import read_log

    return {tag: [(step, value) for step, _, value in events] for tag, events in read_log(run / "tensorboard").items()}


def test_the_pack_rebuilds_annys_bodies_and_checks_the_config(packs):
    folder, teacher_config, teacher_pack, _, joint_pack = packs
    pack = TrainingPack(teacher_pack)
    assert pack.num_bodies == 2 and len(pack.motions) == 2 and list(pack.templates) == [("tshirt", 1000)]
    values = torch.load(teacher_pack, weights_only=True)["body"]["shapes"]
    for row in (0, 1, 2):
        shape = BodyShape(**dict(zip(("gender", "age", "muscle", "weight", "height", "proportions"),
                                     values[row].tolist())))
        anny = Body(shape)
        packed = pack.body(row)
        assert (packed.rest_vertices - anny.rest_vertices).norm(dim=-1).max() < 5e-5  # m
        assert torch.allclose(packed.skin_weights, anny.skin_weights, atol=1e-6)
        assert torch.allclose(packed.rest_joint_positions, anny.rest_joint_positions, atol=1e-6)
    # Training bodies stay away from the held-out ones.
    config = load_config(teacher_config)
    held_out = torch.tensor([list(BodyShape.parse(text).as_dict().values()) for text in config.data.test_bodies])
    assert torch.cdist(values[1:], held_out).min() >= config.data.test_body_margin
    # The teacher's pack has no bones; the joint one has the config's.
    vertices = pack.templates[("tshirt", 1000)].garment.num_vertices
    assert pack.templates[("tshirt", 1000)].bone_vertex is None
    assert TrainingPack(joint_pack).templates[("tshirt", 1000)].bone_distance.shape == (vertices, 32)
    other = apply_overrides(load_config(teacher_config), ["data.resolutions=[1500]"])
    with pytest.raises(ParameterError, match="data.resolutions"):
        PackData(pack, other.data)
    damaged = folder / "damaged.pt"
    damaged.write_bytes(teacher_pack.read_bytes()[:1000])
    with pytest.raises(InputFileError, match="damaged.pt"):
        TrainingPack(damaged)


def test_an_episode_from_the_pack_poses_the_garment_with_its_body(packs):
    _, teacher_config, teacher_pack, _, _ = packs
    data = PackData(TrainingPack(teacher_pack), load_config(teacher_config).data, seed=3)
    episode = data.sample_episode(5)
    vertices = episode.identity.rest.num_vertices
    assert episode.body_vertices.shape == (7, 13718, 3) and episode.garment_lbs.shape == (7, vertices, 3)
    # The garment moves with its body: its centre follows the body's root over the window.
    garment_path = episode.garment_lbs.mean(1) - episode.garment_lbs.mean(1)[0]
    body_path = episode.body_vertices.mean(1) - episode.body_vertices.mean(1)[0]
    assert (garment_path - body_path).norm(dim=-1).max() < 0.05
    assert episode.identity.body.row in (1, 2)


def test_phase_1_trains_and_resumes_with_torch_alone(packs, tmp_path):
    _, teacher_config, teacher_pack, _, _ = packs
    run = tmp_path / "teacher"
    first = train_blocked("--pack", teacher_pack, "--config", teacher_config, "--out", run, "--batch", 2,
                          "--max-steps", 3)
    assert first["step"] == 3 and (run / "index.pt").exists()
    second = train_blocked("--pack", teacher_pack, "--config", teacher_config, "--out", run, "--batch", 2,
                           "--resume")
    assert second["step"] == 6 and second["steps_this_run"] == 3
    losses = logged(run)["loss"]
    assert [step for step, _ in losses] == [1, 2, 3, 4, 5, 6]
    assert all(math.isfinite(value) for _, value in losses)


def test_phase_2_trains_and_resumes_with_torch_alone(packs, tmp_path):
    _, _, _, joint_config, joint_pack = packs
    run = tmp_path / "joint"
    train_blocked("--pack", joint_pack, "--config", joint_config, "--out", run, "--rollout-batch", 2,
                  "--max-steps", 2)
    summary = train_blocked("--pack", joint_pack, "--config", joint_config, "--out", run, "--rollout-batch", 2,
                            "--resume")
    assert summary["step"] == 4
    log = logged(run)
    assert [step for step, _ in log["a_mse"]] == [1, 2, 3, 4]
    assert all(math.isfinite(value) for _, value in log["a_mse"] + log["loss"])


def test_module_a_overfits_one_fixed_batch_of_teacher_frames(packs, tmp_path):
    """A and B learn one fixed pair of C's frames: phase 2's loss there (A's error against C
    plus the physics terms on A's garment, all non-negative) falls at least 5×."""
    from hyperbones.training.from_pack import trainer_for

    _, _, _, joint_config, joint_pack = packs
    config = apply_overrides(load_config(joint_config), ["train.learning_rate=3e-3", "train.device=cpu"])
    trainer = trainer_for(config, tmp_path / "overfit", TrainingPack(joint_pack), rollout_batch=2, progress=False)
    torch.manual_seed(0)
    trainer._extra_terms()  # fills the rollout cache
    fixed = [(trainer.cache.rollouts[0], 4), (trainer.cache.rollouts[-1], 5)]
    trainer.cache.sample = lambda: fixed[trainer.step % 2]
    trainer.config = apply_overrides(trainer.config, ["joint.refresh_every=1000000"])
    trainer.step = 1  # off the refresh schedule
    losses = []
    for _ in range(40):
        losses.append(trainer._advance()["loss"])
        trainer.step += 1
    trainer.close()
    first, last = sum(losses[:2]) / 2, sum(losses[-2:]) / 2
    assert last < first / 5, (first, last)


def test_phase_1_trains_under_torchrun_with_a_batch_per_process(packs, tmp_path):
    """Two processes (DDP over gloo), a batch of two episodes each: one state, the summary counts both."""
    _, teacher_config, teacher_pack, _, _ = packs
    run = tmp_path / "ddp"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
               "-m", "hyperbones.training.from_pack", "--pack", str(teacher_pack), "--config", str(teacher_config),
               "--out", str(run), "--batch", "2", "--max-steps", "2", "--device", "cpu", "--quiet"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=ROOT,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    summaries = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert len(summaries) == 1 and summaries[0]["processes"] == 2 and summaries[0]["step"] == 2
    assert (run / "index.pt").exists()
    assert all(math.isfinite(value) for _, value in logged(run)["loss"])


def test_phase_2_refuses_a_pack_without_its_bones(packs, tmp_path):
    from hyperbones.training.from_pack import main

    _, _, teacher_pack, joint_config, _ = packs
    with pytest.raises(ParameterError, match="teacher.pt: 0 virtual bones per template, the config asks for 32"):
        from hyperbones.training.from_pack import trainer_for

        trainer_for(apply_overrides(load_config(joint_config), ["train.device=cpu"]), tmp_path / "a",
                    TrainingPack(teacher_pack), progress=False)
    assert main(["--pack", str(teacher_pack), "--config", str(joint_config), "--out", str(tmp_path / "b"),
                 "--device", "cpu", "--quiet"]) == 2


def test_timed_steps_times_the_steps_after_the_warm_up(packs, tmp_path):
    """``timed_steps`` (the device scripts' measure): one time per step after the warm-up,
    every step taken and counted, a batch of B counting B episode-steps."""
    from hyperbones.training.from_pack import timed_steps, trainer_for

    _, teacher_config, teacher_pack, _, _ = packs
    config = apply_overrides(load_config(teacher_config), ["train.device=cpu"])
    trainer = trainer_for(config, tmp_path / "timed", TrainingPack(teacher_pack), batch=2, progress=False)
    seconds = timed_steps(trainer, 3, warmup=1)
    trainer.close()
    assert len(seconds) == 3 and all(value > 0 for value in seconds)
    assert trainer.step == 4 and trainer.episode_steps == 8
