"""Training: typed configs, data sampling, losses, the trainer and its checkpoints."""
