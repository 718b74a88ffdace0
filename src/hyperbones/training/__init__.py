"""Training: typed configs, episodes, losses, the teacher and phase-2 trainers, rollout banks, checkpoints."""
