"""The joint trainer and the per-frame runtime run Module A on the same bone window: on the
same motion, identity and weights (the shipped model's, 16-frame window) they give the same
garment, at the window's padded start as well as once it is full."""

import copy

import torch

from hyperbones.body.shape import BodyShape
from hyperbones.physics.material import Material
from hyperbones.runtime.config import RuntimeConfig
from hyperbones.runtime.identity import encode_identity
from hyperbones.models.loading import hyperbones_payload
from hyperbones.runtime.simulator import Simulator
from hyperbones.training import joint
from hyperbones.models.loading import SHIPPED_HYPERBONES
from hyperbones.training.config import HyperBonesTrainingConfig
from hyperbones.training.joint import JointTrainer

from test_training_trainer import TINY


def module_a_alone(module_a, identity) -> Simulator:
    """The runtime without follow or contact: Module A's output as it is."""
    return Simulator(module_a, [identity], config=RuntimeConfig(follow=1.0, loose_follow=1.0))


def test_trainer_and_runtime_give_the_same_module_a_output(tmp_path, body, monkeypatch):
    shipped = hyperbones_payload()["config"]
    values = {"model": shipped["model"], "runtime": shipped["runtime"], "data": {**TINY["data"], "resolutions": [1000]},
              "train": {"init_from": str(SHIPPED_HYPERBONES), "device": "cpu"}, "joint": {"train_teacher": False}}
    trainer = JointTrainer(HyperBonesTrainingConfig.from_dict(values), tmp_path / "run", progress=False)
    window = trainer.config.runtime.window_frames
    assert window == 16

    # A rollout of the walk from its 30th frame (mid-stride: the padded window holds motion)
    # on a body other than the default; C's garment is not needed, LBS stands in for it.
    identity = trainer.data.identity_for("tshirt", 1000, BodyShape(weight=0.7, height=0.3), Material())
    motion = trainer.data.motions[0]
    frames = window + 6
    rotations = motion.joint_rotations[30:30 + frames]
    roots = motion.root_translation[30:30 + frames] * (identity.body.leg_length / body.leg_length)
    posed = identity.body.pose(rotations, roots)
    rollout = trainer.cache.assemble(identity, motion.name, rotations, roots,
                                     identity.skin(posed.skinning_transforms), posed=posed)

    # The trainer's path to Module A's garment (``_runtime_frames_terms``) on each frame t.
    seen = []
    monkeypatch.setattr(joint, "runtime_terms", lambda garment, *args, **kwargs: seen.append(garment.detach()) or {})
    for t in range(frames):
        trainer._runtime_frames_terms([(rollout, t)], collision_weight=1.0)

    # The runtime's: the identity encoded as ``Simulator.load`` encodes it, then one step a frame.
    with torch.no_grad():
        cache = encode_identity(trainer.model, identity.garment, identity.body,
                                rest_vertices=identity.rest.rest_vertices)
    module_a = copy.deepcopy(trainer.model.runtime)
    simulator = module_a_alone(module_a, cache)
    stepped = [simulator.step(rotations[t:t + 1], roots[t:t + 1])[0] for t in range(frames)]

    # The trainer samples t >= 2 (``RolloutCache.sample``), whose windows up to t = 14 reach
    # before the rollout and repeat its first frame, as the runtime's first step fills its
    # window; t = 0, 1 are compared too.
    for t in range(frames):
        assert float((seen[t] - stepped[t]).abs().max()) < 1e-5, f"frame {t}"
    # The window matters: started at the last frame (a window of that frame alone), the
    # runtime puts the garment elsewhere, so the agreement above covers the window's content.
    fresh = module_a_alone(module_a, cache).step(rotations[-1:], roots[-1:])[0]
    assert float((fresh - stepped[-1]).abs().max()) > 0.01
    trainer.close()
