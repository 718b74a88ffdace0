"""Simulation methods (LBS baseline; the neural ones follow) and the simulate / eval pipelines."""
