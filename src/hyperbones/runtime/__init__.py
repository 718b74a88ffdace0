"""Per-frame inference: the HyperBones Simulator and its RuntimeConfig, identity caches, contact
push-out, edge projection, the teacher's rollout, and the methods built on them."""
