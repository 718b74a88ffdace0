"""Training: typed configs, episodes, losses, the teacher and phase-2 trainers, rollout banks,
training states and exports, and the physics reference method (it minimises the training loss)."""
