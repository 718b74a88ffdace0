"""hyperbones train, phase 2: Modules A, B and C in one step, from a phase-1 run, on a tiny garment."""

import json

import pytest
import torch

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.models.loading import load_checkpoint
from hyperbones.training.config import HyperBonesTrainingConfig, JointConfig, TeacherTrainingConfig, load_config
from hyperbones.training.joint import JointTrainer
from hyperbones.training.loss import laplacian
from hyperbones.training.rollouts import MAX_DRAWS, drift
from hyperbones.training.trainer import TeacherTrainer

from test_training_trainer import TINY

TINY_JOINT = {**TINY, "runtime": {"num_bones": 16, "shape_code": 16, "hidden": 32, "uv_features": 4,
                                  "uv_resolution": 16, "conv_channels": [8, 16, 8]},
              "joint": {"cache_size": 2, "rollout_frames": 6, "refresh_every": 2}}


def test_laplacian_of_a_linear_field_vanishes_inside():
    # A 3×3 grid of vertices: the centre's neighbours average to it for a linear field.
    xy = torch.stack(torch.meshgrid(torch.arange(3.0), torch.arange(3.0), indexing="ij"), -1).reshape(-1, 2)
    edges = torch.tensor([[i, i + 1] for i in range(9) if i % 3 < 2] + [[i, i + 3] for i in range(6)])
    values = xy @ torch.tensor([[2.0], [-1.0]])
    assert laplacian(values, edges)[4].abs().item() < 1e-6
    assert laplacian(values, edges)[0].abs().item() > 0.1  # a corner sees only one side


def test_drift_measures_the_last_third():
    skinned = torch.zeros(9, 4, 3)
    positions = skinned.clone()
    positions[6:, :, 2] = 0.05  # the garment rode 5 cm up over the last three frames
    positions[:6, :, 0] = 1.0   # earlier frames do not count
    rise, gap = drift(positions, skinned)
    assert rise == pytest.approx(0.05) and gap == pytest.approx(0.05)


def test_config_kinds(tmp_path):
    joint = tmp_path / "joint.toml"
    joint.write_text("[model]\nlatent = 16\n[runtime]\nuv_resolution = 64\nuse_conv = false\n"
                     "[joint]\nlaplacian_weight = 0.0\n")
    config = load_config(joint)
    assert isinstance(config, HyperBonesTrainingConfig)
    assert config.runtime.uv_resolution == 64 and config.runtime.use_conv is False
    assert config.joint.laplacian_weight == 0.0 and config.joint.interpenetration_weight == JointConfig().interpenetration_weight
    teacher = tmp_path / "teacher.toml"
    teacher.write_text("[model]\nlatent = 16\n")
    assert type(load_config(teacher)) is TeacherTrainingConfig
    bad = tmp_path / "bad.toml"
    bad.write_text("[runtime]\nuse_conv = 1\n[joint]\n")
    with pytest.raises(InputFileError, match="use_conv must be bool"):
        load_config(bad)


def test_frames_per_rollout_must_divide_frames_per_step():
    with pytest.raises(InputFileError, match="frames_per_rollout .4. must divide joint.frames_per_step .6."):
        HyperBonesTrainingConfig.from_dict({"joint": {"frames_per_step": 6, "frames_per_rollout": 4}})
    assert HyperBonesTrainingConfig.from_dict({"joint": {"frames_per_step": 8, "frames_per_rollout": 4}})


def test_joint_steps_from_a_teacher_run(tmp_path, body):
    teacher_run = tmp_path / "teacher"
    phase_one = TeacherTrainer(TeacherTrainingConfig.from_dict(TINY), teacher_run, progress=False, max_steps=2)
    phase_one.train()
    phase_one.close()

    from hyperbones.models.loading import hyperbones_from_checkpoint

    with pytest.raises(InputFileError, match="a teacher checkpoint, not a HyperBones one"):
        hyperbones_from_checkpoint(teacher_run / "checkpoint.pt")

    values = {**TINY_JOINT, "train": {**TINY["train"], "init_from": str(teacher_run / "checkpoint.pt")}}
    config = HyperBonesTrainingConfig.from_dict(values)
    trainer = JointTrainer(config, tmp_path / "joint", progress=False, max_steps=3)
    taught = load_checkpoint(teacher_run / "checkpoint.pt")["model"]
    assert all(torch.equal(trainer.teacher.state_dict()[k], v) for k, v in taught.items())
    runtime_before = [p.detach().clone() for p in trainer.model.runtime.parameters()]
    encoder_before = [p.detach().clone() for p in trainer.model.encoder.parameters()]

    logs = trainer._advance()
    assert len(trainer.cache.rollouts) == 2  # filled up to the cache size before the first step
    for name in ("stretching", "collision", "a_mse", "a_laplacian", "a_interpenetration", "a_stretching"):
        assert name in logs and torch.isfinite(torch.tensor(logs[name]))
    assert logs["a_mse"] > 0
    # One step moved Module A and Module B's heads (their output layers start at zero).
    assert any(not torch.equal(a, b) for a, b in zip(runtime_before, trainer.model.runtime.parameters()))
    assert any(not torch.equal(a, b) for a, b in zip(encoder_before, trainer.model.encoder.parameters()))
    rollout = trainer.cache.rollouts[0]
    assert rollout.positions.shape == (rollout.num_frames, rollout.geometry.rest_vertices.shape[0], 3)
    assert torch.isfinite(rollout.positions).all()

    trainer.step += 1
    first_made = {id(r) for r in trainer.cache.rollouts}
    assert trainer.train() == 3  # the step-2 refresh replaces the oldest rollout
    trainer.close()
    assert len(trainer.cache.rollouts) == 2 and {id(r) for r in trainer.cache.rollouts} != first_made
    payload = load_checkpoint(tmp_path / "joint" / "checkpoint.pt")
    assert payload["step"] == 3 and payload["config"]["joint"]["cache_size"] == 2
    assert any(k.startswith("runtime.") for k in payload["model"]) and any(k.startswith("encoder.") for k in payload["model"])
    resumed = JointTrainer(config, tmp_path / "joint", resume=True, progress=False, max_steps=4)
    assert resumed.train() == 4
    resumed.close()

    # A teacher run can start from a joint checkpoint: it takes that checkpoint's Module C.
    teacher_values = {**TINY, "train": {**TINY["train"], "init_from": str(tmp_path / "joint" / "checkpoint.pt")}}
    again = TeacherTrainer(TeacherTrainingConfig.from_dict(teacher_values), tmp_path / "teacher2", progress=False)
    joint_state = load_checkpoint(tmp_path / "joint" / "checkpoint.pt")["model"]
    assert all(torch.equal(value, joint_state[f"teacher.{name}"]) for name, value in again.teacher.state_dict().items())
    again.close()


def test_joint_steps_with_a_frozen_teacher(tmp_path, body):
    """joint.train_teacher = false: C and the trunk stay as phase 1 left them; A and B's heads
    learn, on a window longer than the paper's three frames."""
    teacher_run = tmp_path / "teacher"
    phase_one = TeacherTrainer(TeacherTrainingConfig.from_dict(TINY), teacher_run, progress=False, max_steps=1)
    phase_one.train()
    phase_one.close()
    values = {**TINY_JOINT, "runtime": {**TINY_JOINT["runtime"], "window_frames": 5},
              "joint": {**TINY_JOINT["joint"], "train_teacher": False, "frames_per_step": 2, "max_gap": 1e-6},
              "train": {**TINY["train"], "init_from": str(teacher_run / "checkpoint.pt")}}
    with pytest.raises(ParameterError, match="trunk_from_runtime needs joint.train_teacher"):
        JointTrainer(HyperBonesTrainingConfig.from_dict(
            {**values, "joint": {**values["joint"], "trunk_from_runtime": True}}), tmp_path / "bad", progress=False)
    trainer = JointTrainer(HyperBonesTrainingConfig.from_dict(values), tmp_path / "joint", progress=False, max_steps=2)
    teacher_before = {k: v.clone() for k, v in trainer.teacher.state_dict().items()}
    runtime_before = [p.detach().clone() for p in trainer.model.runtime.parameters()]
    logs = trainer._advance()
    assert "stretching" not in logs and logs["a_mse"] > 0 and torch.isfinite(torch.tensor(logs["loss"]))
    assert all(torch.equal(v, trainer.teacher.state_dict()[k]) for k, v in teacher_before.items())
    assert any(not torch.equal(a, b) for a, b in zip(runtime_before, trainer.model.runtime.parameters()))
    assert any(r.latents is not None for r in trainer.cache.rollouts)
    # A batch of frames (two of one rollout: encoded and skinned once; three bodies, one search,
    # one joined mesh) scores as the mean of each frame alone.
    first, second = trainer.cache.rollouts[:2]
    samples = [(first, 3), (second, 5), (first, 4)]
    with torch.no_grad():
        together = trainer._runtime_frames_terms(samples, collision_weight=1e5)
        alone = [trainer._runtime_frames_terms([sample], collision_weight=1e5) for sample in samples]
    assert {"a_mse", "a_stretching", "a_collision"} <= set(together)
    for name, value in together.items():
        assert torch.allclose(value, sum(terms[name] for terms in alone) / 3, rtol=1e-4, atol=1e-12), name
    drawn = trainer.cache.sample_frames(6, per_rollout=3)
    assert len(drawn) == 6 and drawn[0][0] is drawn[2][0] and drawn[3][0] is drawn[5][0]
    # No rollout stays within a micrometre of its skinned pose: each refresh drew MAX_DRAWS and kept the last.
    assert trainer.cache.refused == (MAX_DRAWS - 1) * len(trainer.cache.rollouts)
    trainer.step += 1
    assert trainer.train() == 2
    trainer.close()
    # Only A's and B's parameters have optimiser state, and the stored moving average leaves C out.
    assert len(trainer.optimizer.state) == sum(1 for p in trainer.model.parameters() if p.requires_grad)
    raw = torch.load(tmp_path / "joint" / "checkpoint.pt", weights_only=True)
    assert raw["ema"] and not any(k.startswith("teacher.") for k in raw["ema"])

    # A joint run started from a joint checkpoint (fine-tuning) takes A and B too, from the moving average.
    tuned = {**values, "train": {**values["train"], "init_from": str(tmp_path / "joint" / "checkpoint.pt")}}
    fine = JointTrainer(HyperBonesTrainingConfig.from_dict(tuned), tmp_path / "fine", progress=False, max_steps=1)
    average = load_checkpoint(tmp_path / "joint" / "checkpoint.pt")["ema"]
    assert all(torch.equal(value, average[name]) for name, value in fine.model.state_dict().items())
    fine.close()
    other = {**tuned, "runtime": {**tuned["runtime"], "window_frames": 3}}
    with pytest.raises(ParameterError, match="train.init_from has runtime"):
        JointTrainer(HyperBonesTrainingConfig.from_dict(other), tmp_path / "other", progress=False)


def test_a_rollout_bank_is_written_resumed_and_trained_from(tmp_path, body, capsys):
    """hyperbones rollouts fills a bank; the same seed goes on with new draws; phase 2 loads from it."""
    from hyperbones.cli import main
    from hyperbones.training.rollouts import (DRAW_LOG, bank_files, generate_bank, load_rollout, log_draws,
                                              read_draw_log)

    teacher_run = tmp_path / "teacher"
    phase_one = TeacherTrainer(TeacherTrainingConfig.from_dict(TINY), teacher_run, progress=False, max_steps=1)
    phase_one.train()
    phase_one.close()
    bank = tmp_path / "bank"
    values = {**TINY_JOINT, "joint": {**TINY_JOINT["joint"], "train_teacher": False, "bank": str(bank)},
              "train": {**TINY["train"], "init_from": str(teacher_run / "checkpoint.pt")}}
    config = HyperBonesTrainingConfig.from_dict(values)
    generate_bank(config, bank, count=2, seed=3, progress=False)
    generate_bank(config, bank, count=1, seed=3, progress=False)
    files = bank_files(bank)
    assert [f.name for f in files] == ["rollout-s3-00000.pt", "rollout-s3-00001.pt", "rollout-s3-00002.pt"]
    records = [load_rollout(f) for f in files]
    assert records[0]["positions"].dtype == torch.float16 and records[0]["version"] == 1
    assert records[0]["network_dtype"] == "float32"
    assert len({(r["shape"]["weight"], r["motion"]) for r in records}) == 3  # three different draws
    # Every draw is logged (refused ones too), each saved one under its file's name, with its cost.
    draws = read_draw_log(bank / DRAW_LOG)
    assert [d["file"] for d in draws if d["file"]] == [f.name for f in files]
    assert all(d["refused_for"] for d in draws if d["file"] is None)  # only refused draws are not saved
    assert all(d["rollout_s"] > 0 and d["rollout_cpu_s"] > 0 and d["identity_s"] >= 0 and d["frames"] > 2
               for d in draws)
    assert [(d["template"], d["motion"]) for d in draws if d["file"]] == [
        (r["template"], r["motion"]) for r in records]
    with open(bank / DRAW_LOG, "a") as log:
        log.write('{"seed": 3, "ind')  # a process stopped mid-line
    assert read_draw_log(bank / DRAW_LOG) == draws
    log_draws(bank / DRAW_LOG, [{"index": 9}])  # the next process drops the cut line first
    assert read_draw_log(bank / DRAW_LOG) == [*draws, {"index": 9}]
    with open(bank / DRAW_LOG, "a") as log:
        log.write('{"seed": 3, "ind')
        log.write("\n{}\n")
    with pytest.raises(InputFileError, match="line .* is not a JSON record"):
        read_draw_log(bank / DRAW_LOG)
    with pytest.raises(InputFileError, match="draws.jsonl: no draw log"):
        read_draw_log(tmp_path / "no-bank" / DRAW_LOG)

    trainer = JointTrainer(config, tmp_path / "joint", progress=False, max_steps=1)
    rollout = trainer.cache.load(files[0])
    assert torch.allclose(rollout.positions, records[0]["positions"].float())
    assert rollout.body_vertices.shape[0] == rollout.num_frames == records[0]["positions"].shape[0]
    assert trainer.train() == 1
    trainer.close()
    assert len(trainer.cache.rollouts) == 2 and all(r.source for r in trainer.cache.rollouts)  # loaded, not simulated
    assert records[0]["draped"] is False
    draping = HyperBonesTrainingConfig.from_dict({**values, "data": {**values["data"], "drape": True}})
    draping_trainer = JointTrainer(draping, tmp_path / "draping", progress=False)
    carried = draping_trainer.cache.load(files[0])  # rebuilt as it started, whatever the config says
    assert carried.physics.draped is False
    assert torch.equal(carried.physics.garment.vertices, rollout.physics.garment.vertices)
    draping_trainer.close()
    # A draped share in the same bank (hyperbones rollouts --drape), made with the teacher in
    # bfloat16 (--bfloat16): the undraped run rebuilds it draped.
    [draped_file] = generate_bank(draping, bank, count=1, seed=4, progress=False, bfloat16=True)
    saved = load_rollout(draped_file)
    assert saved["draped"] is True and saved["network_dtype"] == "bfloat16"
    assert json.loads((bank / DRAW_LOG).read_text().splitlines()[-1])["identity_s"] > 0  # the drape took its time
    mixed = trainer.cache.load(draped_file)
    assert mixed.physics.draped is True
    assert torch.equal(mixed.physics.garment.vertices, saved["start"])  # the saved start: nothing draped again
    assert not torch.equal(mixed.physics.garment.vertices, mixed.physics.rest.rest_vertices)
    # Its drift (logged) is measured from the drape it started from, skinned along, not from the
    # rest shape (which a draped long skirt hangs ~14 cm RMS from: nine draws in ten were refused).
    logged = json.loads((bank / DRAW_LOG).read_text().splitlines()[-1])
    assert logged["file"] == draped_file.name
    from_drape = drift(mixed.positions, mixed.physics.skin(mixed.skinning, mixed.physics.garment.vertices))
    from_rest = drift(mixed.positions, mixed.physics.skin(mixed.skinning))
    assert (logged["rise_m"], logged["gap_m"]) == pytest.approx(from_drape, abs=1e-3), (from_rest, from_drape)  # float16
    assert abs(from_rest[1] - logged["gap_m"]) > 3e-3, (from_rest, from_drape)
    # A draped file from before starts were saved is draped again, to the same start (cached).
    old_file = tmp_path / "old" / "rollout-s4-00000.pt"
    old_file.parent.mkdir()
    torch.save({key: value for key, value in saved.items() if key != "start"}, old_file)
    assert torch.equal(trainer.cache.load(old_file).physics.garment.vertices, saved["start"])
    bad = {**saved, "start": saved["start"][:-1]}
    torch.save(bad, old_file)
    with pytest.raises(InputFileError, match=r"rollout-s4-00000.pt: a draped start of \(\d+, 3\)"):
        trainer.cache.load(old_file)

    # A rollout that came off the body is measured so, by Warp's search and by torch's alike,
    # and a bank file like it is skipped (refused) when the config checks detachment.
    from hyperbones.geometry.torch_proximity import TorchProximity
    from hyperbones.training.rollouts import detached_above_hips, signed_distances_from_start

    checking = HyperBonesTrainingConfig.from_dict(
        {**values, "joint": {**values["joint"], "max_detached_pct": 5.0, "cache_size": 8}})
    checker = JointTrainer(checking, tmp_path / "checking", progress=False)
    cache = checker.cache
    assert cache.detachment(rollout.physics, rollout.positions, rollout.body_vertices) < 5.0
    lifted = rollout.positions + torch.tensor([0.0, 0.0, 3.0])
    assert cache.detachment(rollout.physics, lifted, rollout.body_vertices) == 100.0
    half = torch.cat([rollout.positions[:3], lifted[3:]])
    warp_pct = cache.detachment(rollout.physics, half, rollout.body_vertices)
    start, canonical = rollout.physics.garment.vertices, rollout.physics.body
    distances = signed_distances_from_start(TorchProximity(canonical.faces), half, rollout.body_vertices, start,
                                            canonical.rest_vertices)
    torch_pct = detached_above_hips(*distances, start, float(canonical.rest_joint_positions[0, 2]))
    assert torch_pct == pytest.approx(warp_pct) and warp_pct > 40.0
    # A skirt's hem swinging out below the hips does not count.
    below = rollout.positions.clone()
    low = start[:, 2] < float(canonical.rest_joint_positions[0, 2])
    assert low.any()
    below[:, low] += torch.tensor([0.0, 0.3, 0.0])
    assert cache.detachment(rollout.physics, below, rollout.body_vertices) < 5.0
    came_off = [bank / "rollout-s9-00000.pt", bank / "rollout-s9-00001.pt"]
    for path in came_off:
        torch.save({**records[0], "positions": records[0]["positions"] + torch.tensor([0.0, 0.0, 3.0]).half()}, path)
    good = {str(f) for f in [*files, draped_file]}
    for step in range(len(good) + 1):  # the good files in any order, then the bad ones all refused and one simulated
        cache.refresh(checker.teacher, step)
    assert cache.refused_files == {str(path) for path in came_off}
    sources = {r.source for r in cache.rollouts}
    assert sources >= good and not any("s9" in source for source in sources)
    checker.close()

    with pytest.raises(InputFileError, match="bad.pt: not a version-1 hyperbones saved rollout"):
        torch.save({"something": 1}, tmp_path / "bad.pt")
        load_rollout(tmp_path / "bad.pt")
    teacher_config = tmp_path / "teacher.toml"
    teacher_config.write_text("[model]\nlatent = 16\n")
    assert main(["rollouts", "--config", str(teacher_config), "--out", str(bank)]) == 2
    assert "not a HyperBones (phase 2) config" in capsys.readouterr().err
    joint_config = tmp_path / "joint.toml"
    joint_config.write_text("[model]\nlatent = 16\n[joint]\n")
    assert main(["rollouts", "--config", str(joint_config), "--out", str(bank), "--templates", "dress,skirt"]) == 2
    assert "--templates skirt: not among the config's data.templates" in capsys.readouterr().err


@pytest.mark.parametrize(("flags", "drape"), [([], True), (["--drape"], True), (["--no-drape"], False)])
def test_rollouts_start_draped_or_carried_whatever_the_config_says(tmp_path, monkeypatch, flags, drape):
    """hyperbones rollouts --drape/--no-drape overrides the config's data.drape; without either the config decides."""
    from hyperbones.cli import main
    from hyperbones.training import rollouts

    config = tmp_path / "joint.toml"
    config.write_text("[model]\nlatent = 16\n[joint]\n[data]\ndrape = true\n")
    made = []
    monkeypatch.setattr(rollouts, "generate_bank", lambda config, *args, **kwargs: made.append(config.data.drape))
    assert main(["rollouts", "--config", str(config), "--out", str(tmp_path / "bank"), *flags]) == 0
    assert made == [drape]
