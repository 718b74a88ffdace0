"""Per-vertex quantities to a UV image and back, as two precomputed sparse matrices.

``UvRaster.build`` rasterises the garment's UV atlas once (per garment and resolution):
each texel centre inside a UV triangle gets that triangle's three vertices with the
barycentric weights of the centre. Texels up to ``pad`` pixels outside the charts take the
nearest covered texel's triangle with barycentrics extrapolated to their own centre, so a
field linear over a triangle continues linearly across the chart border and bilinear
sampling at a border vertex reads no zeros. Texels farther out stay zero (``coverage``
marks the charts themselves).

Reading back, a vertex is the mean of the bilinear samples at each of its UV copies
(several on a seam), so every copy of a seam vertex gets the same value and the surface
never cracks.

Per frame both directions are one sparse @ dense product.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage

from hyperbones.errors import ParameterError
from hyperbones.geometry.geodesic import mesh_components
from hyperbones.geometry.sparse import to_csr

PAD_PIXELS = 2


def _barycentric(points: torch.Tensor, triangles: torch.Tensor) -> torch.Tensor:
    """(N,2) points, (N,3,2) triangles -> (N,3) barycentric coordinates (any sign)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    beta = (v2[:, 0] * v1[:, 1] - v2[:, 1] * v1[:, 0]) / det
    gamma = (v0[:, 0] * v2[:, 1] - v0[:, 1] * v2[:, 0]) / det
    return torch.stack([1 - beta - gamma, beta, gamma], dim=1)


def _fill_from_neighbours(sampler: torch.Tensor, resolved: torch.Tensor, faces: torch.Tensor,
                          max_rings: int = 16) -> torch.Tensor:
    """Give each unresolved row of the (V,R²) sampler the mean of its resolved mesh neighbours' rows."""
    edges = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = torch.unique(torch.cat([edges, edges.flip(1)]), dim=0)  # both directions
    num_vertices = len(resolved)
    for _ in range(max_rings):
        if bool(resolved.all()):
            break
        use = ~resolved[edges[:, 0]] & resolved[edges[:, 1]]
        receivers, senders = edges[use, 0], edges[use, 1]
        if len(receivers) == 0:
            break
        count = torch.bincount(receivers, minlength=num_vertices).to(torch.float64)
        spread = torch.sparse_coo_tensor(torch.stack([receivers, senders]), 1.0 / count[receivers],
                                         (num_vertices, num_vertices), check_invariants=False)
        sampler = (sampler + torch.sparse.mm(spread, sampler)).coalesce()
        resolved = resolved | (count > 0)
    return sampler


@dataclass
class UvRaster:
    """The UV atlas of one garment at one resolution.

    resolution: R (the image is R×R; texel (row, col) has its centre at u = (col+½)/R,
        v = (row+½)/R).
    raster: (R²,V) sparse, image = raster @ per-vertex values.
    sampler: (V,R²) sparse, per-vertex values = sampler @ image.
    coverage: (R,R) float, 1 on texels inside a UV triangle.
    """

    resolution: int
    raster: torch.Tensor
    sampler: torch.Tensor
    coverage: torch.Tensor

    @classmethod
    def build(cls, faces: torch.Tensor, uvs: torch.Tensor, face_uvs: torch.Tensor, num_vertices: int,
              resolution: int, pad: int = PAD_PIXELS) -> "UvRaster":
        """Rasterise the atlas: faces (F,3) int64, uvs (U,2) in [0,1], face_uvs (F,3) int64."""
        if resolution < 4:
            raise ParameterError(f"UV resolution must be at least 4, got {resolution}")
        size = resolution
        corners = (uvs.to(torch.float64)[face_uvs] * size)  # (F,3,2) in pixels
        area = ((corners[:, 1, 0] - corners[:, 0, 0]) * (corners[:, 2, 1] - corners[:, 0, 1])
                - (corners[:, 1, 1] - corners[:, 0, 1]) * (corners[:, 2, 0] - corners[:, 0, 0]))
        usable = torch.nonzero(area.abs() > 1e-12).squeeze(1)
        low = torch.ceil(corners[usable].amin(1) - 0.5).clamp(0, size - 1).long()  # (F',2) first col,row
        high = torch.floor(corners[usable].amax(1) - 0.5).clamp(0, size - 1).long()
        extent = (high - low + 1).clamp_min(0)
        counts = extent[:, 0] * extent[:, 1]
        candidate_face = usable.repeat_interleave(counts)
        offset = torch.arange(int(counts.sum())) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
        width = extent[:, 0].repeat_interleave(counts)
        col = low[:, 0].repeat_interleave(counts) + offset % width
        row = low[:, 1].repeat_interleave(counts) + offset // width
        centre = torch.stack([col, row], 1).to(torch.float64) + 0.5
        bary = _barycentric(centre, corners[candidate_face])
        inside = bary.amin(1) >= -1e-9
        texel = (row * size + col)[inside]
        # Where UV triangles overlap, the one the centre lies deepest inside wins.
        depth = bary[inside].amin(1)
        order = torch.argsort(texel.to(torch.float64) * 4 - depth, stable=True)
        texel, first = texel[order], torch.ones(len(order), dtype=torch.bool)
        first[1:] = texel[1:] != texel[:-1]
        covered_texel = texel[first]
        covered_face = candidate_face[inside][order][first]

        face_of = np.full(size * size, -1, dtype=np.int64)
        face_of[covered_texel.numpy()] = covered_face.numpy()
        covered = (face_of >= 0).reshape(size, size)
        coverage = torch.from_numpy(covered.astype(np.float32))
        if covered.any():
            distance, (near_row, near_col) = ndimage.distance_transform_edt(~covered, return_indices=True)
            filled = (distance <= pad).reshape(-1)
            face_of = np.where(filled, face_of[(near_row * size + near_col).reshape(-1)], -1)
        texels = torch.from_numpy(np.nonzero(face_of >= 0)[0])
        texel_face = torch.from_numpy(face_of[texels.numpy()])
        centres = torch.stack([texels % size, texels // size], 1).to(torch.float64) + 0.5
        weights = _barycentric(centres, corners[texel_face])
        raster = torch.sparse_coo_tensor(
            torch.stack([texels.repeat_interleave(3), faces[texel_face].reshape(-1)]),
            weights.reshape(-1).to(torch.float32), (size * size, num_vertices), check_invariants=False)
        raster = to_csr(raster)

        # Each (vertex, UV) corner pair once; a seam vertex has several.
        pairs = torch.unique(torch.stack([faces.reshape(-1), face_uvs.reshape(-1)], 1), dim=0)
        copies = torch.bincount(pairs[:, 0], minlength=num_vertices).clamp_min(1)
        # A bilinear tap may land on a texel of another chart packed next to this one: such
        # taps are dropped and the rest renormalised. A copy with no tap on its own chart (a
        # chart smaller than a texel) is dropped; a vertex left with no copy at all takes the
        # mean of its mesh neighbours, ring after ring.
        chart = torch.from_numpy(mesh_components(len(uvs), face_uvs)).long()  # chart of each UV index
        texel_chart = torch.full((size * size,), -1, dtype=torch.int64)
        texel_chart[texels] = chart[face_uvs[texel_face, 0]]
        position = uvs.to(torch.float64)[pairs[:, 1]] * size - 0.5  # in texel-centre units
        base = torch.floor(position)
        frac = position - base
        taps, tap_weights = [], []
        for dc, dr in ((0, 0), (1, 0), (0, 1), (1, 1)):
            c = (base[:, 0] + dc).clamp(0, size - 1).long()
            r = (base[:, 1] + dr).clamp(0, size - 1).long()
            taps.append(r * size + c)
            tap_weights.append((frac[:, 0] if dc else 1 - frac[:, 0]) * (frac[:, 1] if dr else 1 - frac[:, 1]))
        taps, tap_weights = torch.stack(taps, 1), torch.stack(tap_weights, 1)  # (P,4)
        own = (texel_chart[taps] == chart[pairs[:, 1]][:, None]).to(torch.float64)
        kept = (tap_weights * own).sum(1)
        good = kept > 1e-9
        tap_weights = tap_weights * own / kept.clamp_min(1e-12)[:, None]
        copies = torch.bincount(pairs[good, 0], minlength=num_vertices)
        sampler = torch.sparse_coo_tensor(
            torch.stack([pairs[good, 0].repeat_interleave(4), taps[good].reshape(-1)]),
            (tap_weights[good] / copies[pairs[good, 0], None]).reshape(-1),
            (num_vertices, size * size), check_invariants=False).coalesce()
        sampler = _fill_from_neighbours(sampler, copies > 0, faces)
        return cls(size, raster, to_csr(sampler.to(torch.float32)), coverage)

    def state_dict(self) -> dict:
        """Plain tensors (COO indices and values) for saving."""
        raster, sampler = self.raster.to_sparse_coo(), self.sampler.to_sparse_coo()
        return {"resolution": self.resolution, "coverage": self.coverage,
                "raster_indices": raster.indices(), "raster_values": raster.values(),
                "raster_shape": list(raster.shape),
                "sampler_indices": sampler.indices(), "sampler_values": sampler.values(),
                "sampler_shape": list(sampler.shape)}

    @classmethod
    def from_state_dict(cls, state: dict) -> "UvRaster":
        def matrix(name: str) -> torch.Tensor:
            return to_csr(torch.sparse_coo_tensor(state[f"{name}_indices"], state[f"{name}_values"],
                                                  tuple(state[f"{name}_shape"]), check_invariants=True))

        return cls(int(state["resolution"]), matrix("raster"), matrix("sampler"), state["coverage"])

    def to(self, device: torch.device | str) -> "UvRaster":
        with warnings.catch_warnings():  # moving a CSR matrix builds it anew without invariant checks
            warnings.filterwarnings("ignore", message="Sparse invariant checks are implicitly disabled")
            return UvRaster(self.resolution, self.raster.to(device), self.sampler.to(device),
                            self.coverage.to(device))

    def dense(self) -> "UvRaster":
        """The same maps as dense matrices: the constants of an exported graph (ONNX has no
        sparse product); (R²,V) and (V,R²) floats, so 8·R²·V bytes in all."""
        return UvRaster(self.resolution, self.raster.to_dense(), self.sampler.to_dense(), self.coverage)

    def rasterize(self, values: torch.Tensor) -> torch.Tensor:
        """(N,V,C) per-vertex values -> (N,C,R,R) images."""
        batch, _, channels = values.shape
        flat = values.permute(1, 0, 2).reshape(values.shape[1], batch * channels)
        image = (self.raster @ flat).reshape(self.resolution, self.resolution, batch, channels)
        return image.permute(2, 3, 0, 1)

    def sample(self, images: torch.Tensor) -> torch.Tensor:
        """(N,C,R,R) images -> (N,V,C) values at the vertices (mean over their UV copies)."""
        batch, channels = images.shape[:2]
        flat = images.permute(2, 3, 0, 1).reshape(self.resolution * self.resolution, batch * channels)
        return (self.sampler @ flat).reshape(-1, batch, channels).permute(1, 0, 2)
