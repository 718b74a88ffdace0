"""Garments: the Garment type, OBJ / MakeHuman import, procedural templates, canonical drape."""

from hyperbones.garment.garment import Garment

__all__ = ["Garment"]
