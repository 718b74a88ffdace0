"""A garment's proxy: a coarse copy of it that the runtime's contact and projection correct in
its place, and the map that carries their correction back to every vertex.

The runtime's correction layer costs per vertex (a body search, a share of a sparse solve),
Module A hardly does (its cost is per bone and per texel), so at 5k vertices the correction
was three quarters of a frame. The proxy is the garment decimated to about P vertices (quadric
edge collapse that keeps boundaries and picks among the garment's own vertices, so each proxy
vertex *is* a garment vertex); every garment vertex is tied to the proxy triangle nearest to it
at rest by barycentric weights. Per frame the runtime corrects the proxy's vertices, spreads
their correction over the garment with those weights, and Jacobi edge sweeps on the whole
garment remove the stretch Module A leaves below the proxy's scale (``runtime.simulator``).
The frame's cost then hardly grows with the garment's vertices. Measurements:
docs/experiments/*-runtime-proxy.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.sparse import to_csr
from hyperbones.runtime.config import MIN_PROXY_VERTICES


@dataclass
class GarmentProxy:
    """A garment's proxy and its embedding.

    vertex: (P,) int64 the garment vertices that are the proxy's vertices;
    faces: (Fp,3) int64 the proxy's triangles, indexing ``vertex``;
    corners: (V,3) int64 the proxy vertices (indices into ``vertex``) of each garment vertex's triangle;
    weights: (V,3) float32 its barycentric weights there (non-negative, summing to 1);
    target: the vertex count asked for (``RuntimeConfig.proxy_vertices``).
    """

    vertex: torch.Tensor
    faces: torch.Tensor
    corners: torch.Tensor
    weights: torch.Tensor
    target: int
    main_corner: torch.Tensor = field(init=False, repr=False, compare=False)
    """(V,) the proxy vertex each garment vertex leans on most (its largest weight): whose skin
    record (nearest face, distance) stands in for the garment vertex's own."""
    _matrix: torch.Tensor | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.main_corner = self.corners.gather(1, self.weights.argmax(1, keepdim=True))[:, 0]

    @property
    def num_vertices(self) -> int:
        return self.vertex.shape[0]

    @classmethod
    def build(cls, rest_vertices: torch.Tensor, faces: torch.Tensor, count: int) -> "GarmentProxy":
        """The proxy of a garment at rest, (V,3) vertices and (F,3) faces, with about ``count``
        vertices (pymeshlab's quadric edge collapse; a decimation keeps a few more or fewer)."""
        if count < MIN_PROXY_VERTICES:
            raise ParameterError(f"a garment proxy needs at least {MIN_PROXY_VERTICES} vertices, got {count}")
        vertex, proxy_faces = _decimated(rest_vertices.detach().cpu().double().numpy(),
                                         faces.detach().cpu().numpy(), count)
        corners, weights = _embedding(rest_vertices.detach().cpu().float(), vertex, proxy_faces)
        return cls(vertex, proxy_faces, corners, weights, int(count))

    def spread(self, values: torch.Tensor) -> torch.Tensor:
        """(P,k) values at the proxy's vertices -> (V,k) at the garment's, by the barycentric
        weights: one product with the (V,P) sparse matrix of them (made once; a tenth of the
        time of gathering the corners and summing)."""
        matrix = self._matrix
        if matrix is None or matrix.device != values.device or matrix.dtype != values.dtype:
            rows = torch.arange(self.corners.shape[0], device=self.corners.device)[:, None].expand_as(self.corners)
            coo = torch.sparse_coo_tensor(torch.stack([rows.reshape(-1), self.corners.reshape(-1)]),
                                          self.weights.reshape(-1), (self.corners.shape[0], self.num_vertices),
                                          check_invariants=True)
            self._matrix = matrix = to_csr(coo).to(device=values.device, dtype=values.dtype)
        return matrix @ values

    def to(self, device: torch.device | str) -> "GarmentProxy":
        return GarmentProxy(self.vertex.to(device), self.faces.to(device), self.corners.to(device),
                            self.weights.to(device), self.target)

    def state_dict(self) -> dict:
        return {"vertex": self.vertex, "faces": self.faces, "corners": self.corners, "weights": self.weights,
                "target": self.target}

    @classmethod
    def from_state_dict(cls, state: dict, num_vertices: int) -> "GarmentProxy":
        """The proxy of a saved identity of ``num_vertices``; ``ValueError`` saying what is wrong
        when its tensors do not fit together (``Identity.load`` names the file)."""
        if not isinstance(state, dict) or set(state) != {"vertex", "faces", "corners", "weights", "target"}:
            raise ValueError("its proxy entry is not a table of vertex, faces, corners, weights, target")
        vertex, faces, corners, weights, target = (state[k] for k in ("vertex", "faces", "corners", "weights", "target"))
        if type(target) is not int or target < MIN_PROXY_VERTICES:
            raise ValueError(f"proxy target {target!r} is not a whole number of at least {MIN_PROXY_VERTICES}")
        for name, value, ndim, floating in (("vertex", vertex, 1, False), ("faces", faces, 2, False),
                                            ("corners", corners, 2, False), ("weights", weights, 2, True)):
            if not isinstance(value, torch.Tensor) or value.ndim != ndim or value.is_floating_point() != floating:
                raise ValueError(f"proxy {name} is not a {ndim}-d {'float' if floating else 'integer'} tensor")
        count = vertex.shape[0]
        if faces.shape[1:] != (3,) or corners.shape != (num_vertices, 3) or weights.shape != (num_vertices, 3):
            raise ValueError(f"proxy faces {tuple(faces.shape)}, corners {tuple(corners.shape)} or weights "
                             f"{tuple(weights.shape)} do not fit a garment of {num_vertices} vertices")
        for name, index, bound in (("vertex", vertex, num_vertices), ("faces", faces, count), ("corners", corners, count)):
            if index.numel() and (int(index.min()) < 0 or int(index.max()) >= bound):
                raise ValueError(f"proxy {name} has indices outside [0, {bound})")
        if not torch.isfinite(weights).all() or bool((weights < 0).any()):
            raise ValueError("proxy weights are negative or not finite")
        return cls(vertex.long(), faces.long(), corners.long(), weights.float(), target)


def _decimated(vertices: np.ndarray, faces: np.ndarray, count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(V,3) float64, (F,3) -> the garment vertices kept (P,) and the decimated triangles (Fp,3)
    over them. Without optimal placement, edge collapse only ever keeps one of an edge's two
    ends, so every vertex left is one of the input's, found again by its exact position."""
    from scipy.spatial import cKDTree

    try:
        import pymeshlab
    except ImportError:
        raise ParameterError("making a garment proxy needs pymeshlab, which is not installed here: load identity "
                             "caches saved with their proxy (`hyperbones identity`), or run with "
                             "--runtime proxy_vertices=0") from None

    meshes = pymeshlab.MeshSet()
    meshes.add_mesh(pymeshlab.Mesh(vertices, faces.astype(np.int32)))
    # A triangle mesh has about twice as many faces as vertices; boundaries (hems, cuffs,
    # collars) weigh double so that the garment keeps its outline.
    meshes.meshing_decimation_quadric_edge_collapse(targetfacenum=int(2 * count), preserveboundary=True,
                                                    boundaryweight=2.0, preservenormal=True, preservetopology=True,
                                                    optimalplacement=False, planarquadric=True, autoclean=True)
    mesh = meshes.current_mesh()
    distance, vertex = cKDTree(vertices).query(mesh.vertex_matrix())
    if distance.max() > 1e-9:
        raise RuntimeError(f"garment proxy: decimation moved a vertex by {distance.max():.2e} m")
    return torch.from_numpy(vertex).long(), torch.from_numpy(mesh.face_matrix().astype(np.int64))


def _embedding(rest_vertices: torch.Tensor, vertex: torch.Tensor, proxy_faces: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Each of the (V,3) garment vertices' nearest point on the proxy at rest, as (V,3) corner
    indices into ``vertex`` and (V,3) barycentric weights; a proxy vertex gets weight 1 on itself."""
    from hyperbones.geometry.torch_proximity import TorchProximity

    search = TorchProximity(proxy_faces, device="cpu")
    search.update(rest_vertices[vertex])
    nearest = search.query(rest_vertices, max_distance=float("inf"))
    if not bool(nearest.found.all()):
        raise RuntimeError("garment proxy: some vertex found no proxy triangle")
    corners = proxy_faces[nearest.face]
    weights = nearest.barycentric.clamp_min(0.0)
    weights = weights / weights.sum(1, keepdim=True)
    # Exact on the proxy's own vertices (a float32 search may give 0.9999 there).
    own = torch.stack([vertex, torch.arange(len(vertex))], 1)
    corners[own[:, 0]] = own[:, 1:].expand(-1, 3)
    weights[own[:, 0]] = torch.tensor([1.0, 0.0, 0.0])
    return corners, weights.float()
