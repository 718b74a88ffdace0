"""What the viewer shows: one garment on one body through one motion with one method and fabric."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from hyperbones.body.shape import BodyShape
from hyperbones.physics.material import Material

VIEW_METHODS = {"HyperBones": "hyperbones", "LBS (skinning only)": "lbs"}
# Fabric sliders: each scales fields of the default cloth (HOOD's) by its factor.
FABRIC_FIELDS = {"stretch": ("lame_mu", "lame_lambda"), "bending": ("bending",), "density": ("density",)}
FABRIC_RANGE = (0.25, 4.0)


@dataclass(frozen=True)
class Choice:
    """One scene: garment (a template or a file), motion (a built-in or a .bvh file), method
    (a ``jobs.methods`` name), body shape, fabric factors ({"stretch", "bending", "density"} ->
    a factor of the default cloth's), vertices (a template's resolution; None: the default)
    and frames (the first N of the motion; None: all)."""

    garment: str = "tshirt"
    motion: str = "walk"
    method: str = "hyperbones"
    body: BodyShape = BodyShape()
    fabric: tuple[tuple[str, float], ...] = field(default=tuple((name, 1.0) for name in FABRIC_FIELDS))
    vertices: int | None = 2500
    frames: int | None = 300

    def material(self) -> Material:
        """The cloth: the default's fields scaled by the fabric factors."""
        cloth = Material()
        scaled = {}
        for name, factor in self.fabric:
            for key in FABRIC_FIELDS[name]:
                scaled[key] = getattr(cloth, key) * factor
        return replace(cloth, **scaled)
