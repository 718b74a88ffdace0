"""The body–garment graph the trunk reads: garment nodes, body nodes, mesh and world edges.

One builder serves both uses of the shared trunk:
  - Module C (teacher), every frame: the garment state at t, the body at t and t+1;
  - Module B (canonical encoder), once per identity: the canonical garment at rest on the
    A-pose body (zero velocity, body still).

Nodes are the V garment vertices followed by the body vertices that some world edge
touches (the rest of the body cannot send anything). World edges run from body to
garment: each garment vertex within ``world_radius`` of the body receives one edge from
each corner of its nearest body face (found with the Warp BVH at time t).

Features are scaled to be of order one before the learned normalisers (centimetres for
lengths, cm per frame for velocities, grams ×10 for masses):

node (NODE_FEATURES = 21): velocity (3), unit normal (3), type one-hot free/pinned/body
    (3), prescribed displacement to t+1 (3; pinned and body nodes, zero for free ones),
    mass (1), material μ, λ, k_b, ρ in [0,1] over HOOD's ranges (4), step length dt/(1/30) (1),
    and the cloth's internal acceleration −∇(E_stretch + E_bend)/m in units of g, compressed
    by asinh (3; zero on body nodes: a stretched stiff cloth reaches thousands of g). The
    last one is not in HOOD's list: it hands the network the local physics it would
    otherwise have to learn from relative positions.
mesh edge (EDGE_FEATURES = 8), both directions: x_s − x_r and its length, now and at rest.
world edge (8): x_garment(t) − body(t) and its length, x_garment(t) − body(t+1) and its length.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hyperbones.geometry.surface import Nearest
from hyperbones.models.mgn import EdgeSet
from hyperbones.physics.energies import GRAVITY, bending_energy, stretching_energy
from hyperbones.physics.material import BatchMaterial, Material, material_features

NODE_FEATURES = 21
EDGE_FEATURES = 8
LENGTH_SCALE = 100.0  # metres -> centimetres
MASS_SCALE = 1e4  # kg -> 0.1 g
FRAME_DT = 1.0 / 30.0
WORLD_RADIUS = 0.05  # m; garment vertices farther from the body get no world edge
FREE, PINNED, BODY = 0, 1, 2


@dataclass
class GarmentTopology:
    """Everything about one garment the graph needs that does not change per frame.

    rest_vertices: (V,3) rest shape; faces: (F,3); pinned_mask: (V,) bool;
    masses: (V,) kg; mesh_senders/mesh_receivers: (2U,) both directions of every edge;
    material: the cloth (a ``BatchMaterial`` for several garments in one, ``training.episode_batch``).
    """

    rest_vertices: torch.Tensor
    faces: torch.Tensor
    pinned_mask: torch.Tensor
    masses: torch.Tensor
    mesh_senders: torch.Tensor
    mesh_receivers: torch.Tensor
    material: Material | BatchMaterial

    @classmethod
    def build(cls, rest_vertices: torch.Tensor, faces: torch.Tensor, pinned: torch.Tensor, masses: torch.Tensor,
              material: Material) -> "GarmentTopology":
        """rest_vertices (V,3), faces (F,3), pinned (P,) indices, masses (V,) kg."""
        pairs = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).sort(dim=1).values
        edges = torch.unique(pairs, dim=0)
        mask = torch.zeros(len(rest_vertices), dtype=torch.bool, device=rest_vertices.device)
        mask[pinned] = True
        return cls(rest_vertices.float(), faces, mask, masses.float(),
                   torch.cat([edges[:, 0], edges[:, 1]]), torch.cat([edges[:, 1], edges[:, 0]]), material)

    @property
    def num_vertices(self) -> int:
        return self.rest_vertices.shape[0]

    def to(self, device: torch.device | str) -> "GarmentTopology":
        material = self.material.to(device) if isinstance(self.material, BatchMaterial) else self.material
        return GarmentTopology(self.rest_vertices.to(device), self.faces.to(device), self.pinned_mask.to(device),
                               self.masses.to(device), self.mesh_senders.to(device), self.mesh_receivers.to(device),
                               material)


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals: (V,3), (F,3) -> (V,3)."""
    corners = vertices[faces]
    face_normals = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], dim=-1)
    normals = torch.zeros_like(vertices).index_add_(0, faces.reshape(-1), face_normals.repeat_interleave(3, 0))
    return normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def internal_acceleration(positions: torch.Tensor, rest) -> torch.Tensor:
    """(V,3) −∇(E_stretch + E_bend)/m, m/s²: the acceleration the cloth's own forces give each
    vertex at ``positions`` (no gradient flows through it). rest: ``ClothRest``."""
    with torch.enable_grad():
        x = positions.detach().requires_grad_(True)
        energy = stretching_energy(x, rest) + bending_energy(x, rest)
        (gradient,) = torch.autograd.grad(energy, x)
    return -gradient / rest.vertex_masses.to(x).clamp_min(1e-12)[:, None]


@dataclass
class ClothGraph:
    """node_features (N,21), edge_sets {"mesh","world"}, and the V garment nodes first."""

    node_features: torch.Tensor
    edge_sets: dict[str, EdgeSet]
    num_garment: int


def build_graph(topology: GarmentTopology, positions: torch.Tensor, velocities: torch.Tensor,
                pinned_next: torch.Tensor, body_now: torch.Tensor, body_next: torch.Tensor, body_faces: torch.Tensor,
                nearest: Nearest, dt: float = FRAME_DT, internal_acceleration: torch.Tensor | None = None,
                world_radius: float = WORLD_RADIUS) -> ClothGraph:
    """The graph of one step t -> t+1.

    Several garments, each on its own body, make one graph as one garment on one body
    (``training.episode_batch``): their meshes concatenated, with a ``BatchMaterial``, and
    their B bodies laid one after another in body_now, body_next (B·Vb,3) and body_faces
    (B·Fb,3, indices offset); every node then reads its own garment's fabric.

    Args:
        topology: the garment's fixed part.
        positions: (V,3) garment at t; velocities: (V,3) per-frame displacement x(t) − x(t−1).
        pinned_next: (V,3) where pinned vertices are at t+1 (rows of free vertices ignored).
        body_now, body_next: (Vb,3) body vertices at t and t+1; body_faces (Fb,3).
        nearest: ``BodyProximity.query(positions)`` against the body at t.
        dt: the step's length in seconds (the teacher's first, settling step is longer).
        internal_acceleration: (V,3) ``internal_acceleration`` of the garment at t, m/s² (zero when None).
    """
    device, num_garment = positions.device, topology.num_vertices
    near = nearest.found & (nearest.signed_distance.abs() < world_radius)
    receivers = torch.nonzero(near).squeeze(1).repeat_interleave(3)
    body_ids = body_faces[nearest.face[near]].reshape(-1).to(device)  # 3 corners per close vertex
    used, body_local = torch.unique(body_ids, return_inverse=True)
    senders = body_local + num_garment

    body_normals = vertex_normals(body_next, body_faces)[used]
    body_step = body_next[used] - body_now[used]
    garment_normals = vertex_normals(positions, topology.faces)
    prescribed = torch.where(topology.pinned_mask[:, None], pinned_next - positions, torch.zeros_like(positions))
    kind = torch.full((num_garment,), FREE, dtype=torch.int64, device=device)
    kind[topology.pinned_mask] = PINNED
    num_body = len(used)
    kinds = torch.nn.functional.one_hot(torch.cat([kind, torch.full((num_body,), BODY, device=device)]), 3).float()
    if isinstance(topology.material, BatchMaterial):
        material = topology.material.node_features(used, body_now.shape[0]).to(device)
    else:
        material = torch.tensor(material_features(topology.material), device=device).expand(num_garment + num_body, 4)
    masses = torch.cat([topology.masses, torch.zeros(num_body, device=device)])[:, None] * MASS_SCALE
    step = torch.full((num_garment + num_body, 1), dt / FRAME_DT, device=device)
    node_features = torch.cat([
        torch.cat([velocities, body_step]) * LENGTH_SCALE,
        torch.cat([garment_normals, body_normals]),
        kinds,
        torch.cat([prescribed, body_step]) * LENGTH_SCALE,
        masses, material, step,
        torch.asinh(torch.cat([internal_acceleration if internal_acceleration is not None
                               else torch.zeros_like(positions), torch.zeros(num_body, 3, device=device)]) / GRAVITY),
    ], dim=-1)

    mesh_s, mesh_r = topology.mesh_senders, topology.mesh_receivers
    now = positions[mesh_s] - positions[mesh_r]
    rest = topology.rest_vertices[mesh_s] - topology.rest_vertices[mesh_r]
    mesh_features = torch.cat([now, now.norm(dim=-1, keepdim=True), rest, rest.norm(dim=-1, keepdim=True)], -1)
    to_now = positions[receivers] - body_now[body_ids]
    to_next = positions[receivers] - body_next[body_ids]
    world_features = torch.cat([to_now, to_now.norm(dim=-1, keepdim=True), to_next, to_next.norm(dim=-1, keepdim=True)], -1)
    return ClothGraph(
        node_features=node_features,
        edge_sets={"mesh": EdgeSet(mesh_s, mesh_r, mesh_features * LENGTH_SCALE),
                   "world": EdgeSet(senders, receivers, world_features * LENGTH_SCALE)},
        num_garment=num_garment,
    )


def canonical_graph(topology: GarmentTopology, body_vertices: torch.Tensor, body_faces: torch.Tensor,
                    nearest: Nearest, world_radius: float = WORLD_RADIUS) -> ClothGraph:
    """The graph Module B encodes once per identity: the garment at rest on the still A-pose body.

    body_vertices: (Vb,3) the canonical body; nearest: ``BodyProximity.query`` of the rest
    garment against it. Zero velocity, the body still, pins where they are, and no internal
    force (the garment is at its own rest shape): the same features the teacher reads.
    """
    rest = topology.rest_vertices
    return build_graph(topology, rest, torch.zeros_like(rest), rest, body_vertices, body_vertices, body_faces,
                       nearest, world_radius=world_radius)
