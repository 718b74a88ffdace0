"""Body models. Default backend: Anny with the 31-joint ``cmu_mb`` rig."""

from hyperbones.body.anny_body import Body, PosedBody, anny_model, body_for
from hyperbones.body.shape import PHENOTYPE_KEYS, BodyShape
from hyperbones.body.skeleton import JOINT_NAMES, JOINT_PARENTS, NUM_JOINTS

__all__ = ["Body", "BodyShape", "PosedBody", "anny_model", "body_for", "PHENOTYPE_KEYS",
           "JOINT_NAMES", "JOINT_PARENTS", "NUM_JOINTS"]
