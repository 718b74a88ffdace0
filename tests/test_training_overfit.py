"""Module A can learn: the joint trainer's own steps, all on one cached frame of a rollout of
the shipped teacher, fit that frame (a small model on a ~1000-vertex tshirt, on the CPU)."""

from hyperbones.models.loading import SHIPPED_TEACHER
from hyperbones.training.config import HyperBonesTrainingConfig
from hyperbones.training.joint import JointTrainer

from test_training_trainer import TINY

STEPS = 300
L_3D = ("a_mse", "a_laplacian", "a_interpenetration")  # runtime_terms' L_3D (physics on A is off here)


def test_module_a_overfits_one_cached_frame(tmp_path, body, monkeypatch):
    values = {"model": {"latent": 64, "blocks": 15},  # the shipped teacher's trunk, frozen: C makes the target
              "data": {**TINY["data"], "resolutions": [1000]},
              "train": {"learning_rate": 1e-3, "init_from": str(SHIPPED_TEACHER), "device": "cpu"},
              "runtime": {"num_bones": 32, "shape_code": 16, "hidden": 64, "uv_features": 4, "uv_resolution": 32,
                          "conv_channels": [8, 16, 8]},
              "joint": {"cache_size": 1, "rollout_frames": 8, "refresh_every": 10**6, "train_teacher": False,
                        "physics_on_runtime": False}}
    trainer = JointTrainer(HyperBonesTrainingConfig.from_dict(values), tmp_path / "run", progress=False)
    rollout = trainer.cache.refresh(trainer.teacher, step=0)  # C from the LBS start over 8 frames of the walk
    last = rollout.num_frames - 1
    monkeypatch.setattr(trainer.cache, "sample", lambda: (rollout, last))
    trainer.step = 1  # no refresh (step % refresh_every) replaces the frame

    losses = []
    for _ in range(STEPS):
        logs = trainer._advance()  # one optimiser step of A (and B's heads) on the frame
        trainer.step += 1
        assert set(L_3D) <= set(logs) and "a_stretching" not in logs
        losses.append(sum(logs[name] for name in L_3D))
    final = trainer._runtime_frames_terms([(rollout, last)], collision_weight=1.0)
    trainer.close()
    final_loss = sum(float(final[name].detach()) for name in L_3D)
    assert losses[0] > 1.0  # cm²: A starts centimetres off C's garment (virtual-bone skinning)
    assert final_loss < losses[0] / 10, (losses[0], final_loss)
