"""B training identities as one garment on one body, so one optimiser step advances B episodes.

One garment graph is too small to keep a GPU (or both CPU cores) busy. Laid one after
another, B garments are one mesh of N = ΣV_b vertices (indices offset) and their B bodies
(one Anny topology, different shapes and poses) one "multi-body" of B·Vb vertices and B·F
faces (indices offset by b·Vb). The garments share no vertex, edge or face, and each one's
world edges reach only its own body (``geometry.batched_proximity.BatchedProximity``), so
``build_graph``, ``teacher_step``, ``physics_terms`` and ``constrain_step`` (given
``vertex_garment``) treat the batch as one garment and give each garment what it would get
alone. Fabrics differ per garment: the concatenated rest state carries a ``BatchMaterial``.

The per-identity rest states are concatenated as built, not rebuilt from the joined mesh:
``ClothRest.from_mesh`` takes one material, and the masses depend on it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch

from hyperbones.errors import ParameterError
from hyperbones.geometry.batched_proximity import BatchedProximity, multi_body_faces
from hyperbones.models.cloth_graph import GarmentTopology
from hyperbones.physics.cloth import ClothRest
from hyperbones.physics.material import BatchMaterial
from hyperbones.physics.strain_limit import StrainLimiter
from hyperbones.training.episode import Identity


@dataclass
class EpisodeBatch:
    """B identities' garments concatenated into one, on their B bodies laid one after another.

    names: the identities' names; rest, topology, limiter: the concatenated garment's
    ``ClothRest`` (material: a ``BatchMaterial``), ``GarmentTopology`` and ``StrainLimiter``;
    vertex_offsets: (B+1,) int64 where each garment's vertices start (the last is N);
    episode_of_vertex: (N,) int64 the garment of each vertex; sizes: the B vertex counts;
    body_faces: (B·F,3) the multi-body's faces, body b's offset by b·Vb;
    one_body_faces: (F,3) the faces of one body; num_body_vertices: Vb.
    """

    names: tuple[str, ...]
    rest: ClothRest
    topology: GarmentTopology
    limiter: StrainLimiter
    vertex_offsets: torch.Tensor
    episode_of_vertex: torch.Tensor
    sizes: tuple[int, ...]
    body_faces: torch.Tensor
    one_body_faces: torch.Tensor
    num_body_vertices: int

    @classmethod
    def of(cls, identities: Sequence[Identity], body_faces: torch.Tensor) -> "EpisodeBatch":
        """The batch of ``identities`` (their bodies share one mesh: ``body_faces`` (F,3)),
        on the device of their tensors."""
        if not identities:
            raise ParameterError("an episode batch needs at least one identity")
        body_sizes = {identity.body.rest_vertices.shape[0] for identity in identities}
        if len(body_sizes) != 1:
            raise ParameterError(f"the identities' bodies must share one mesh; got vertex counts {sorted(body_sizes)}")
        num_body_vertices = body_sizes.pop()
        rests = [identity.rest for identity in identities]
        if any(isinstance(rest.material, BatchMaterial) for rest in rests):
            raise ParameterError("an identity of an episode batch already holds a batch")
        sizes = tuple(rest.num_vertices for rest in rests)
        rest, offsets = joined_rest(rests)
        material = rest.material
        topology = _joined_topology([identity.topology for identity in identities], offsets, material)
        limiter = _joined_limiter([identity.limiter for identity in identities], offsets)
        if not (topology.num_vertices == len(limiter.inverse_masses) == rest.num_vertices):
            raise ParameterError("an identity's rest state, topology and limiter disagree on its vertex count")
        return cls(tuple(identity.name for identity in identities), rest, topology, limiter, offsets,
                   material.vertex_garment, sizes, multi_body_faces(body_faces, len(identities), num_body_vertices),
                   body_faces, num_body_vertices)

    @property
    def num_episodes(self) -> int:
        return len(self.sizes)

    @property
    def num_vertices(self) -> int:
        return self.rest.num_vertices

    def split(self, values: torch.Tensor) -> list[torch.Tensor]:
        """(N,...) per-vertex values of the batch -> B views (V_b,...), one per garment."""
        return list(torch.split(values, self.sizes))

    def multi_body(self, bodies: Sequence[torch.Tensor] | torch.Tensor) -> torch.Tensor:
        """B bodies' vertices, a list of (Vb,3) or (B,Vb,3), -> the multi-body (B·Vb,3)."""
        stacked = torch.cat(list(bodies)) if not isinstance(bodies, torch.Tensor) else bodies.reshape(-1, 3)
        if stacked.shape[0] != self.num_episodes * self.num_body_vertices:
            raise ParameterError(f"expected {self.num_episodes} bodies of {self.num_body_vertices} vertices, "
                                 f"got {stacked.shape[0]} vertices")
        return stacked

    def proximity(self, device: str | torch.device | None = None, **search_options) -> BatchedProximity:
        """The nearest-face search of the batch's garments on their own bodies (on the batch's
        device when None); search_options: ``TorchProximity``'s."""
        device = self.vertex_offsets.device if device is None else device
        return BatchedProximity(self.one_body_faces, self.num_body_vertices, self.vertex_offsets, device,
                                **search_options)

    def to(self, device: str | torch.device) -> "EpisodeBatch":
        """The batch on ``device`` (the limiter rebuilds its sparse matrices there)."""
        return replace(self, rest=self.rest.to(device), topology=self.topology.to(device),
                       limiter=self.limiter.to(device), vertex_offsets=self.vertex_offsets.to(device),
                       episode_of_vertex=self.episode_of_vertex.to(device), body_faces=self.body_faces.to(device),
                       one_body_faces=self.one_body_faces.to(device))


def _shifted(tensors: Sequence[torch.Tensor], offsets: torch.Tensor) -> torch.Tensor:
    """Per-garment vertex indices (any shape, first axis the elements) joined, garment b's shifted by offsets[b]."""
    return torch.cat([tensor + offset for tensor, offset in zip(tensors, offsets.tolist())])


def joined_rest(rests: Sequence[ClothRest]) -> tuple[ClothRest, torch.Tensor]:
    """Garments' rest states (one fabric each) as one rest state of their meshes laid one after
    another, with a ``BatchMaterial``; and (B+1,) int64 where each garment's vertices start.
    Energies on it are the sums of each garment's own."""
    sizes = [rest.num_vertices for rest in rests]
    device = rests[0].rest_vertices.device
    offsets = torch.tensor((0, *sizes), device=device).cumsum(0)
    material = BatchMaterial.concatenate([rest.material for rest in rests], [len(rest.faces) for rest in rests],
                                         [len(rest.hinges) for rest in rests], sizes,
                                         dtype=rests[0].face_areas.dtype, device=device)
    return _joined_rest(rests, offsets, material), offsets


def _joined_rest(rests: Sequence[ClothRest], offsets: torch.Tensor, material: BatchMaterial) -> ClothRest:
    """The garments' rest states one after another (indices shifted), with the batch's fabric."""
    def joined(name: str) -> torch.Tensor:
        return torch.cat([getattr(rest, name) for rest in rests])

    return ClothRest(
        rest_vertices=joined("rest_vertices"),
        faces=_shifted([rest.faces for rest in rests], offsets),
        dm_inv=joined("dm_inv"),
        face_areas=joined("face_areas"),
        vertex_masses=joined("vertex_masses"),
        hinges=_shifted([rest.hinges for rest in rests], offsets),
        hinge_lengths=joined("hinge_lengths"),
        hinge_areas=joined("hinge_areas"),
        hinge_rest_angles=joined("hinge_rest_angles"),
        edges=_shifted([rest.edges for rest in rests], offsets),
        edge_lengths=joined("edge_lengths"),
        material=material,
        num_nonmanifold_edges=sum(rest.num_nonmanifold_edges for rest in rests),
        num_boundary_edges=sum(rest.num_boundary_edges for rest in rests),
        num_degenerate_faces=sum(rest.num_degenerate_faces for rest in rests),
    )


def _joined_topology(topologies: Sequence[GarmentTopology], offsets: torch.Tensor,
                     material: BatchMaterial) -> GarmentTopology:
    """The garments' graph topologies one after another (indices shifted), with the batch's fabric.

    Each garment's mesh edges keep their order (its forward then backward directions), so
    each vertex sums its messages in the order it would alone."""
    return GarmentTopology(
        rest_vertices=torch.cat([t.rest_vertices for t in topologies]),
        faces=_shifted([t.faces for t in topologies], offsets),
        pinned_mask=torch.cat([t.pinned_mask for t in topologies]),
        masses=torch.cat([t.masses for t in topologies]),
        mesh_senders=_shifted([t.mesh_senders for t in topologies], offsets),
        mesh_receivers=_shifted([t.mesh_receivers for t in topologies], offsets),
        material=material,
    )


def _joined_limiter(limiters: Sequence[StrainLimiter], offsets: torch.Tensor) -> StrainLimiter:
    """The garments' strain limiters as one (its sparse matrices built over the joined mesh);
    they must share their band and sweep count."""
    bands = {(limiter.stretch, limiter.compression, limiter.iterations) for limiter in limiters}
    if len(bands) != 1:
        raise ParameterError(f"the identities' strain limiters differ in band or sweeps: {sorted(bands)}")
    stretch, compression, iterations = bands.pop()
    return StrainLimiter(_shifted([limiter.edges for limiter in limiters], offsets),
                         torch.cat([limiter.rest_lengths for limiter in limiters]),
                         torch.cat([limiter.inverse_masses for limiter in limiters]),
                         torch.cat([limiter.edge_counts for limiter in limiters]), stretch, compression, iterations)


__all__ = ["EpisodeBatch", "joined_rest"]
