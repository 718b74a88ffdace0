"""Geometry: pure, batched tensor functions (rotations, skinning, body proximity, geodesics, UV maps, ...)."""
