"""Geometry: pure, batched tensor functions (rotations, skinning, ...)."""
