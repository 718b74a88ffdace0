"""Simulation methods (LBS, teacher, physics, hyperbones) and the simulate / eval / check pipelines."""
