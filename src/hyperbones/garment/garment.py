"""The Garment value: a triangle mesh with a UV atlas, pinned vertices and a material."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch

from hyperbones.errors import ParameterError
from hyperbones.physics.material import Material


@dataclass(frozen=True)
class Garment:
    """A garment in the canonical space (Anny A-pose body standing on z = 0; metres, Z up).

    vertices: (V,3) float32 positions.
    faces: (F,3) int64 triangles (counter-clockwise seen from outside the body).
    uvs: (U,2) float32 texture coordinates in [0,1].
    face_uvs: (F,3) int64 indices into ``uvs`` per face corner; a vertex on a seam has
        several UVs, one per side of the seam.
    pinned: (P,) int64 indices of vertices attached to the body (a waistband), maybe empty.
    material: the cloth.
    name: a label.
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    uvs: torch.Tensor
    face_uvs: torch.Tensor
    pinned: torch.Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.int64))
    material: Material = field(default_factory=Material)
    name: str = "garment"

    def __post_init__(self) -> None:
        v, f = self.vertices, self.faces
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise ParameterError(f"garment {self.name!r}: vertices must be (V,3) with V >= 3, got {tuple(v.shape)}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1:
            raise ParameterError(f"garment {self.name!r}: faces must be (F,3), got {tuple(f.shape)}")
        if self.face_uvs.shape != f.shape:
            raise ParameterError(f"garment {self.name!r}: face_uvs must match faces {tuple(f.shape)}, got {tuple(self.face_uvs.shape)}")
        if self.uvs.ndim != 2 or self.uvs.shape[1] != 2:
            raise ParameterError(f"garment {self.name!r}: uvs must be (U,2), got {tuple(self.uvs.shape)}")
        if int(f.min()) < 0 or int(f.max()) >= len(v):
            raise ParameterError(f"garment {self.name!r}: a face refers to a vertex that does not exist")
        if int(self.face_uvs.min()) < 0 or int(self.face_uvs.max()) >= len(self.uvs):
            raise ParameterError(f"garment {self.name!r}: a face refers to a UV that does not exist")
        if len(self.pinned) and (int(self.pinned.min()) < 0 or int(self.pinned.max()) >= len(v)):
            raise ParameterError(f"garment {self.name!r}: a pinned index is out of range")
        if not torch.isfinite(v).all():
            raise ParameterError(f"garment {self.name!r}: vertex positions contain NaN or infinity")

    @property
    def num_vertices(self) -> int:
        return self.vertices.shape[0]

    def with_vertices(self, vertices: torch.Tensor) -> "Garment":
        """The same garment (topology, UVs, pins, material) with other canonical positions."""
        return replace(self, vertices=vertices.to(torch.float32))

    def edges(self) -> torch.Tensor:
        """(E,2) int64 unique undirected edges, smaller index first."""
        pairs = torch.cat([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        pairs = torch.sort(pairs, dim=1).values
        return torch.unique(pairs, dim=0)
