"""Cloth material: HOOD's inference defaults, changeable from the command line (``--material k=v``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace

import torch

from hyperbones.errors import ParameterError


@dataclass(frozen=True)
class Material:
    """Cloth parameters in SI units (REFERENCE.md, "Material").

    lame_mu, lame_lambda: StVK Lamé coefficients, Pa.
    thickness: m. density: areal density, kg/m². bending: bending stiffness k_b.
    """

    lame_mu: float = 23600.0
    lame_lambda: float = 44400.0
    thickness: float = 4.7e-4
    density: float = 0.20022
    bending: float = 3.9626e-5

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ParameterError(f"material {f.name}={value!r} must be a positive number")

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def parse(cls, text: str | None) -> "Material":
        """``mu=30000,bending=1e-4``; keys: mu, lambda, thickness, density, bending (or full field names)."""
        aliases = {"mu": "lame_mu", "lambda": "lame_lambda", "lame_mu": "lame_mu", "lame_lambda": "lame_lambda",
                   "thickness": "thickness", "density": "density", "bending": "bending"}
        if text is None or text.strip() in ("", "default"):
            return cls()
        values: dict[str, float] = {}
        for item in filter(None, (part.strip() for part in text.split(","))):
            key, sep, raw = (s.strip() for s in item.partition("="))
            if not sep:
                raise ParameterError(f"--material: expected key=value, got {item!r}")
            if key not in aliases:
                raise ParameterError(f"--material: unknown key {key!r}; known keys: mu, lambda, thickness, density, bending")
            if aliases[key] in values:  # "mu=1,lame_mu=2" too
                raise ParameterError(f"--material: {aliases[key]} given twice")
            try:
                values[aliases[key]] = float(raw)
            except ValueError:
                raise ParameterError(f"--material: {key}={raw!r} is not a number") from None
        return cls(**values)


# HOOD's training ranges (REFERENCE.md, "Material"): (low, high, log-scale).
TRAINING_RANGES: dict[str, tuple[float, float, bool]] = {
    "lame_mu": (15909.0, 63636.0, True),
    "lame_lambda": (3535.0, 93334.0, False),
    "bending": (6.37e-8, 1.31e-3, True),
    "density": (0.0434, 0.7, False),
}


def material_features(material: Material) -> list[float]:
    """The four trained-over parameters (μ, λ, k_b, ρ) mapped to [0, 1] over HOOD's ranges
    (log scale for μ and k_b); values outside the ranges map outside [0, 1]."""
    out = []
    for name, (low, high, log) in TRAINING_RANGES.items():
        value = getattr(material, name)
        if log:
            value, low, high = math.log(value), math.log(low), math.log(high)
        out.append((value - low) / (high - low))
    return out


@dataclass
class BatchMaterial:
    """The fabrics of several garments concatenated into one mesh (``training.episode_batch``),
    per element: tensors that broadcast where ``Material``'s floats do, so the energies
    (``physics.energies``) read a batch's ``ClothRest.material`` unchanged.

    lame_mu, lame_lambda, thickness: (F,) per face, Pa, Pa, m; bending: (H,) per hinge;
    density: (V,) per vertex, kg/m² (``ClothRest.with_material`` rescales masses by it);
    features: (B,4) ``material_features`` of each garment's fabric, float32 (the graph's);
    vertex_garment: (V,) int64 the garment each vertex belongs to, 0 … B−1 in mesh order;
    materials: the B fabrics themselves.
    """

    lame_mu: torch.Tensor
    lame_lambda: torch.Tensor
    thickness: torch.Tensor
    density: torch.Tensor
    bending: torch.Tensor
    features: torch.Tensor
    vertex_garment: torch.Tensor
    materials: tuple[Material, ...]

    @classmethod
    def concatenate(cls, materials: Sequence[Material], face_counts: Sequence[int], hinge_counts: Sequence[int],
                    vertex_counts: Sequence[int], dtype: torch.dtype = torch.float32,
                    device: torch.device | str | None = None) -> "BatchMaterial":
        """Garment b's fabric ``materials[b]`` on its ``face_counts[b]`` faces, ``hinge_counts[b]``
        hinges and ``vertex_counts[b]`` vertices, the garments one after another."""
        def per(counts: Sequence[int], name: str) -> torch.Tensor:
            values = torch.tensor([getattr(m, name) for m in materials], dtype=torch.float64)
            return values.repeat_interleave(torch.tensor(list(counts))).to(dtype=dtype, device=device)

        garments = torch.arange(len(materials), device=device)
        return cls(per(face_counts, "lame_mu"), per(face_counts, "lame_lambda"), per(face_counts, "thickness"),
                   per(vertex_counts, "density"), per(hinge_counts, "bending"),
                   torch.tensor([material_features(m) for m in materials], device=device),
                   garments.repeat_interleave(torch.tensor(list(vertex_counts), device=device)), tuple(materials))

    def node_features(self, body_nodes: torch.Tensor, num_body_vertices: int) -> torch.Tensor:
        """(V+M,4) the graph's material features: each garment vertex's own fabric's, then for
        each of the M ``body_nodes`` (flat vertex ids of the B bodies laid one after another,
        ``num_body_vertices`` in all) the fabric of the garment on that body."""
        per_body = num_body_vertices // self.features.shape[0]
        garment = torch.cat([self.vertex_garment, body_nodes.to(self.vertex_garment) // per_body])
        return self.features[garment]

    def to(self, *args, **kwargs) -> "BatchMaterial":
        """Move/cast the per-element tensors like ``Tensor.to`` (features stay float32, indices int64)."""
        device = self.lame_mu.to(*args, **kwargs).device
        return replace(self, **{name: getattr(self, name).to(*args, **kwargs)
                                for name in ("lame_mu", "lame_lambda", "thickness", "density", "bending")},
                       features=self.features.to(device), vertex_garment=self.vertex_garment.to(device))


def sample_material(uniform) -> Material:
    """A random material over HOOD's ranges; ``uniform()`` returns a float in [0, 1)."""
    values = {}
    for name, (low, high, log) in TRAINING_RANGES.items():
        u = uniform()
        values[name] = math.exp(math.log(low) + u * (math.log(high) - math.log(low))) if log else low + u * (high - low)
    return Material(**values)
