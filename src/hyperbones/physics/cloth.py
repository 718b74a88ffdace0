"""Rest-state precomputation of a cloth triangle mesh (REFERENCE.md, "Energies"), done once per garment.

Everything the energies and metrics need that depends only on the rest shape lives in
``ClothRest``: inverse rest matrices, rest areas, lumped masses, the hinge (interior edge)
table for bending and the undirected edge list for the GAPS edge metric.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch

from hyperbones.errors import ParameterError
from hyperbones.physics.material import BatchMaterial, Material


def triangle_areas(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Areas of the triangles ``faces`` of ``vertices``: (...,V,3), (F,3) -> (...,F)."""
    corners = vertices[..., faces, :]  # (...,F,3,3)
    cross = torch.linalg.cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :], dim=-1)
    return 0.5 * cross.norm(dim=-1)


def dihedral_angles(vertices: torch.Tensor, hinges: torch.Tensor) -> torch.Tensor:
    """Signed dihedral angle of each hinge: (...,V,3), (E,4) -> (...,E), radians in (-π, π].

    A hinge is [i, j, k, l]: i-j the shared edge, k and l the opposite vertices, with the
    face (i, j, k) in its own winding order. θ = atan2(ê·(n1×n2), n1·n2) (REFERENCE.md,
    "Bending"); θ = 0 when the two faces are coplanar and unfolded.

    The normals are left unnormalised: atan2 is invariant to scaling both arguments by
    |n1||n2| > 0, so this is the same angle without the 1/|n| that makes gradients NaN at
    degenerate faces. n2 is built from i, j, l alone (not from the second face's stored
    winding), so a mesh with inconsistently wound faces still reads flat as θ = 0.
    """
    x_i, x_j, x_k, x_l = (vertices[..., hinges[:, c], :] for c in range(4))
    edge = x_j - x_i
    n1 = torch.linalg.cross(edge, x_k - x_i, dim=-1)
    n2 = torch.linalg.cross(x_l - x_i, edge, dim=-1)
    edge_length = edge.square().sum(-1).clamp_min(1e-30).sqrt()
    sine = (torch.linalg.cross(n1, n2, dim=-1) * edge).sum(-1) / edge_length
    cosine = (n1 * n2).sum(-1)
    # atan2's gradient is 0/0 at (0, 0) (a degenerate face); feed it a harmless point there
    # and mask the result, so the gradient stays finite (the "double where" trick). Nearly
    # degenerate counts too: |n1||n2| below 1e-6 l⁴ (the two faces' height/edge ratios
    # multiply to under 1e-6). There the angle is undefined and its gradient grows as
    # 1/height (9e6 N at 1e-12 m in float32); a triangle of 6e-11 m² that contact had
    # flattened gave the teacher NaN forces.
    magnitude = sine.square() + cosine.square()  # (|n1||n2|)²
    degenerate = (magnitude < 1e-40) | (magnitude < (1e-6 * edge_length ** 4).square())
    angle = torch.atan2(torch.where(degenerate, torch.zeros_like(sine), sine),
                        torch.where(degenerate, torch.ones_like(cosine), cosine))
    return torch.where(degenerate, torch.zeros_like(angle), angle)


def _local_rest_matrices(rest_vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(F,2,2) D_m: columns are x0−x2 and x1−x2 written in the triangle's own orthonormal 2D frame."""
    corners = rest_vertices[faces]
    d0, d1 = corners[:, 0] - corners[:, 2], corners[:, 1] - corners[:, 2]
    len0 = d0.norm(dim=-1).clamp_min(1e-30)
    axis_u = d0 / len0[:, None]
    normal = torch.linalg.cross(d0, d1, dim=-1)
    axis_v = torch.linalg.cross(normal, axis_u, dim=-1)
    axis_v = axis_v / axis_v.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    rows = torch.stack([torch.stack([len0, (d1 * axis_u).sum(-1)], -1),
                        torch.stack([torch.zeros_like(len0), (d1 * axis_v).sum(-1)], -1)], dim=-2)
    return rows


def _uv_rest_matrices(uv_rest: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(F,2,2) D_m from UVs in metres, per vertex (V,2) or per face corner (F,3,2)."""
    corners = uv_rest[faces] if uv_rest.dim() == 2 else uv_rest
    return torch.stack([corners[:, 0] - corners[:, 2], corners[:, 1] - corners[:, 2]], dim=-1)


def _edge_tables(faces: torch.Tensor) -> dict[str, torch.Tensor | int]:
    """Unique undirected edges (U,2) and the hinge table (E,4) [i, j, k, l] (see ``dihedral_angles``)."""
    # Half-edge c of face f runs corner c -> c+1 with corner c+2 opposite.
    start = faces.reshape(-1)
    end = faces[:, [1, 2, 0]].reshape(-1)
    opposite = faces[:, [2, 0, 1]].reshape(-1)
    keys = torch.stack([torch.minimum(start, end), torch.maximum(start, end)], dim=-1)
    edges, inverse, counts = torch.unique(keys, dim=0, return_inverse=True, return_counts=True)
    # Group half-edges by their undirected edge: after a stable sort, an edge's half-edges
    # sit at first[e], first[e]+1, ...
    order = torch.sort(inverse, stable=True).indices
    first = torch.cumsum(counts, 0) - counts
    manifold = torch.nonzero(counts == 2).squeeze(-1)
    half_a, half_b = order[first[manifold]], order[first[manifold] + 1]
    hinges = torch.stack([start[half_a], end[half_a], opposite[half_a], opposite[half_b]], dim=-1)
    hinge_faces = torch.stack([half_a // 3, half_b // 3], dim=-1)
    # Two copies of one triangle share all three edges with k == l: no hinge to bend.
    proper = hinges[:, 2] != hinges[:, 3]
    return {
        "edges": edges,
        "hinges": hinges[proper],
        "hinge_faces": hinge_faces[proper],
        "num_nonmanifold": int((counts > 2).sum()) + int((~proper).sum()),
        "num_boundary": int((counts == 1).sum()),
    }


@dataclass
class ClothRest:
    """Rest-state tensors of one garment mesh (REFERENCE.md, "Energies" and "Metrics").

    rest_vertices: (V,3) canonical 3D template, metres. faces: (F,3) int64.
    dm_inv: (F,2,2) inverse rest matrices D_m⁻¹ (zero for degenerate rest faces).
    face_areas: (F,) rest areas A_f⁰ of the rest used for D_m (UV area when UVs were given).
    vertex_masses: (V,) m_i = Σ_f ρ A_f⁰ / 3, kg.
    hinges: (E,4) interior edges [i, j, k, l]; hinge_lengths (E,) rest |x_j − x_i|;
    hinge_areas: (E,2) rest areas of the faces (i,j,k) and (j,i,l);
    hinge_rest_angles: (E,) rest dihedral angles (stored; HOOD's bending uses θ⁰ = 0).
    edges: (U,2) all unique undirected edges, edge_lengths: (U,) rest lengths (3D template).
    num_nonmanifold_edges: edges shared by more than two faces (or by a duplicated face),
    left out of bending. num_boundary_edges, num_degenerate_faces: for reports.
    material: the cloth parameters the energies use (per element for several garments
    concatenated into one mesh: a ``BatchMaterial``, ``training.episode_batch``).
    """

    rest_vertices: torch.Tensor
    faces: torch.Tensor
    dm_inv: torch.Tensor
    face_areas: torch.Tensor
    vertex_masses: torch.Tensor
    hinges: torch.Tensor
    hinge_lengths: torch.Tensor
    hinge_areas: torch.Tensor
    hinge_rest_angles: torch.Tensor
    edges: torch.Tensor
    edge_lengths: torch.Tensor
    material: Material | BatchMaterial
    num_nonmanifold_edges: int = 0
    num_boundary_edges: int = 0
    num_degenerate_faces: int = 0

    @classmethod
    def from_mesh(
        cls,
        rest_vertices: torch.Tensor,
        faces: torch.Tensor,
        material: Material | None = None,
        uv_rest: torch.Tensor | None = None,
    ) -> "ClothRest":
        """Precompute the rest state of a triangle mesh.

        Args:
            rest_vertices: (V,3) rest positions, metres (floating dtype kept).
            faces: (F,3) vertex indices.
            material: cloth parameters; HOOD's defaults when None.
            uv_rest: optional rest shape for stretching, in metres: (V,2) or per-corner
                (F,3,2) UVs. When given, D_m and A_f⁰ (hence masses) come from the UVs;
                bending and the edge metric still use the 3D template.
        """
        material = material or Material()
        if rest_vertices.dim() != 2 or rest_vertices.shape[-1] != 3:
            raise ParameterError(f"rest_vertices must be (V,3), got {tuple(rest_vertices.shape)}")
        if faces.dim() != 2 or faces.shape[-1] != 3 or faces.shape[0] == 0:
            raise ParameterError(f"faces must be a non-empty (F,3) array, got {tuple(faces.shape)}")
        rest_vertices = rest_vertices if rest_vertices.is_floating_point() else rest_vertices.float()
        faces = faces.to(device=rest_vertices.device, dtype=torch.int64)
        if int(faces.min()) < 0 or int(faces.max()) >= rest_vertices.shape[0]:
            raise ParameterError("faces index vertices that do not exist")

        if uv_rest is None:
            dm = _local_rest_matrices(rest_vertices, faces)
        else:
            uv_rest = uv_rest.to(rest_vertices)
            if uv_rest.shape not in ((rest_vertices.shape[0], 2), (faces.shape[0], 3, 2)):
                raise ParameterError(f"uv_rest must be (V,2) or (F,3,2), got {tuple(uv_rest.shape)}")
            dm = _uv_rest_matrices(uv_rest, faces)
        determinant = dm[:, 0, 0] * dm[:, 1, 1] - dm[:, 0, 1] * dm[:, 1, 0]
        face_areas = 0.5 * determinant.abs()
        # A zero-area rest face has no D_m⁻¹; giving it zero area and D_m⁻¹ removes it from
        # the membrane energy instead of filling it with inf.
        scale = (dm.abs().amax(dim=(-1, -2)) ** 2).clamp_min(1e-30)
        degenerate = determinant.abs() <= 1e-12 * scale
        safe_dm = torch.where(degenerate[:, None, None], torch.eye(2, dtype=dm.dtype, device=dm.device), dm)
        dm_inv = torch.where(degenerate[:, None, None], torch.zeros_like(dm), torch.linalg.inv(safe_dm))
        face_areas = torch.where(degenerate, torch.zeros_like(face_areas), face_areas)

        vertex_masses = torch.zeros(rest_vertices.shape[0], dtype=rest_vertices.dtype, device=rest_vertices.device)
        vertex_masses.index_add_(0, faces.reshape(-1), (material.density * face_areas / 3.0).repeat_interleave(3))

        tables = _edge_tables(faces)
        hinges, edges = tables["hinges"], tables["edges"]
        areas_3d = triangle_areas(rest_vertices, faces)
        return cls(
            rest_vertices=rest_vertices,
            faces=faces,
            dm_inv=dm_inv,
            face_areas=face_areas,
            vertex_masses=vertex_masses,
            hinges=hinges,
            hinge_lengths=(rest_vertices[hinges[:, 1]] - rest_vertices[hinges[:, 0]]).norm(dim=-1),
            hinge_areas=areas_3d[tables["hinge_faces"]],
            hinge_rest_angles=dihedral_angles(rest_vertices, hinges),
            edges=edges,
            edge_lengths=(rest_vertices[edges[:, 1]] - rest_vertices[edges[:, 0]]).norm(dim=-1),
            material=material,
            num_nonmanifold_edges=tables["num_nonmanifold"],
            num_boundary_edges=tables["num_boundary"],
            num_degenerate_faces=int(degenerate.sum()),
        )

    def with_material(self, material: Material) -> "ClothRest":
        """The same rest state with other cloth parameters (masses rescaled to the new density)."""
        masses = self.vertex_masses * (material.density / self.material.density)
        return replace(self, material=material, vertex_masses=masses)

    def to(self, *args, **kwargs) -> "ClothRest":
        """Move/cast the floating tensors like ``Tensor.to`` (index tensors only change device)."""
        device = self.rest_vertices.to(*args, **kwargs).device
        changes = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, torch.Tensor):
                if value.is_floating_point():
                    changes[f.name] = value.to(*args, **kwargs)
                else:
                    changes[f.name] = value.to(device=device)
        if isinstance(self.material, BatchMaterial):
            changes["material"] = self.material.to(*args, **kwargs)
        return replace(self, **changes)

    @property
    def num_vertices(self) -> int:
        return self.rest_vertices.shape[0]
