"""Every setting of the per-frame runtime in one typed, frozen config.

The runtime (``runtime.simulator``) takes Module A's output as a target, carries the
garment from the last frame towards it, pushes it out of the body and pulls its edges back
towards their rest lengths. Each knob of those steps is a field here, so that a checkpoint,
``metrics.json`` and ``report.json`` say which values produced a result, and
``--runtime key=value,...`` changes any of them without editing code. Why the defaults are
what they are: ``docs/experiments/*runtime*.md``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, get_type_hints

from hyperbones.errors import ParameterError
from hyperbones.physics.energies import COLLISION_EPSILON

MAX_ROUNDS = 64  # push-out and contact rounds: more is no setting but a frame that never ends
MAX_ITERATIONS = 1000  # projection iterations per round, for the same reason
MAX_UV_RESOLUTION = 1024  # the paper's 512 and room above it; past this an image no longer fits a frame
MIN_PROXY_VERTICES = 100  # below this a decimated garment loses its shape (sleeves become slabs)


@dataclass(frozen=True)
class RuntimeConfig:
    """The per-frame runtime's settings (lengths in metres, shares in (0, 1])."""

    uv_resolution: int = 0
    """R of the UV images the Conv-MLP runs on (0: the model's training resolution). The
    Conv-MLP is fully convolutional and its output is sampled bilinearly, so a coarser image
    costs a quarter per halving with the same per-vertex detail wherever texels still cover it.
    The shipped model stores 24 (40 until 2026-11-29, 32 until 2026-11-30; on validation the
    means move by 0.4 % or less, docs/experiments/*-runtime-push-out-one-launch.md, *-conv-mlp-24.md)."""
    conv_mlp: bool = True
    """Add Module A's second stage (the Conv-MLP's displacement, read back from the UV image) to
    the garment its bones skin; off: the bones' garment alone, and no UV stage runs. The
    runtime's contact then does what the Conv-MLP did for contact (docs/experiments/*-realtime-runtime-4.md)."""
    bfloat16: bool = False
    """Run the Conv-MLP in bfloat16 (its weights and inputs; the rest stays float32) where the
    device has bfloat16 units (GPUs, x86 with AVX512-BF16 or AMX): about half its time there, at
    ~0.5 mm of displacement. Elsewhere bfloat16 is emulated, several times slower than float32, so
    the ``Simulator`` runs float32 instead and says so in ``conv_mlp_dtype``. The shipped model
    stores it on (validated)."""
    follow: float = 0.6
    """Share of the way from the carried garment to Module A's output taken each frame by cloth on
    the skin (1: Module A's output as it is); the cloth lags as a damped first-order system."""
    loose_follow: float = 0.4
    """The same share for loose cloth (``follow_far`` or more from the skin): it lags and settles later."""
    carry_lag: float = 0.5
    """Share of the character's last-but-one frame-to-frame motion in what carries loose cloth, so
    it takes up the character's accelerations over two frames instead of one."""
    follow_near: float = 0.01
    """Cloth nearer the skin than this is carried by the skin under it (and follows with ``follow``)."""
    follow_far: float = 0.04
    """Cloth farther than this is carried rigidly with the character (and follows with
    ``loose_follow``); between the two, both blend linearly."""
    contact: bool = True
    """Resolve contact with the posed body (push-out, untangling, edge projection); off: no body
    is used at all (with both shares at 1 this is Module A alone, ``hyperbones-raw``)."""
    contact_margin: float = COLLISION_EPSILON
    """Vertices inside the body or nearer than this are pushed out to this distance from its surface."""
    query_distance: float = 0.05
    """How far from each garment vertex body faces are looked for in the first push-out of a frame.
    Nothing reads what a search finds beyond ``follow_far`` (the follow), ``plane_reach`` and the
    margin, so any range at least as far as those gives the same garment; a nearer one lets the
    BVH skip more of the far cloth (0.1 before 2026-11-29: bit-identical, ~1 ms less a 5k dress frame)."""
    round_query_distance: float = 0.04
    """The same after a projection round, which moves vertices by millimetres (a nearer bound lets
    the BVH skip the far cloth). Below ``follow_far`` the garment changes: cloth between the two
    is carried rigidly instead of by the skin."""
    round_search_gap: float = 0.0
    """After a projection round, a vertex found outside the body and certainly farther than this
    from it (its distance then, less how far it has moved since) is not searched again: it keeps
    its face, skin point and distance, which only the next round's planes and the next frame's
    follow read. Push-outs stay exact: a vertex that may be nearer than the margin is searched.
    0 (or ``round_query_distance`` and more): every vertex within reach is searched (the exact answer).
    The shipped model stores 3 mm (1 cm until 2026-11-29): on validation ε_c rises from 0.006 to
    0.014 % (a third of the 2026-11-28 runtime's), the rest holds, and a 5k frame is ~8 % cheaper
    (docs/experiments/*-runtime-push-out-one-launch.md)."""
    push_rounds: int = 16
    """Push-outs at most per push-out step: a vertex pushed off one face in a crease can land
    inside the next one; the second push takes it out of both faces, or halfway between two
    body parts pressed closer than twice the margin, where it stops. Only the vertices still
    inside are searched again. On validation no step took more than 8; on the held-out clips
    16 and 64 give the same garments. The cap bounds a frame's worst case (4 until 2026-11-29,
    then 64 while a push went one face at a time: docs/experiments/*-push-out-creases.md)."""
    plane_reach: float = 0.03
    """Vertices this close to the skin keep to the outside of their face's plane while edges are
    projected, and are the ones untangling looks at."""
    contact_rounds: int = 2
    """Rounds of edge projection then push-out per frame, each from the last round's nearest faces."""
    untangle: bool = True
    """After the first push-out, bring back vertices pushed out on a limb's far side from their
    neighbours (only with the edge projection, whose edges say who the neighbours are)."""
    untangle_cosine: float = 0.3
    """A vertex whose skin normal points against the sum of its neighbours' (cosine below minus
    this) is on the far side of a limb from them."""
    projection_iterations: int = 5
    """Local/global projective-dynamics steps per contact round (0: push-out only, no projection)."""
    projection_anchor: float = 0.02
    """How strongly each vertex keeps to its input position in the projection, against an edge's
    weight of 1 (a weak anchor lets the garment wander frame after frame)."""
    projection_stretch: float = 0.0
    """Edges up to this fraction longer than at rest are left alone by the projection."""
    projection_compression: float = 0.0
    """Edges up to this fraction shorter than at rest are left alone by the projection."""

    proxy_vertices: int = 0
    """Correct a coarse copy of the garment with about this many vertices instead of the garment
    itself (0: the garment; a garment with no more vertices than this is corrected itself):
    the contact searches and the projection then cost per proxy vertex, not per garment vertex,
    and their correction reaches every vertex by barycentric weights (``runtime.garment_proxy``).
    The follow runs on every vertex; after the spread, ``proxy_sweeps`` edge sweeps and a
    push-out of the vertices near the skin finish the garment. The shipped model stores 1000
    (since 2026-11-29): the 5k frame 0.61-0.65x; on validation at 1,500 vertices ε_e -12 %,
    ε_a -17 %, inertia +1.4 % against correcting every vertex, at 5k inertia +8 %
    (docs/experiments/*-runtime-proxy.md)."""
    proxy_sweeps: int = 15
    """With a proxy: Jacobi sweeps over the whole garment after the proxy's correction is spread
    on it, each pulling every edge towards its rest length, the skin planes of ``plane_reach``
    kept (read from each vertex's main proxy corner): they remove the stretch Module A leaves
    between the proxy's vertices (``physics.strain_limit`` with no band). 0: none."""
    proxy_relaxation: float = 2.0
    """Over-relaxation of those sweeps (1: each vertex moves by the mean of its edges' moves;
    up to 2: further, converging in fewer sweeps; 15 at 2 equal 30 at 1 on validation)."""
    proxy_push_reach: float = 0.01
    """With a proxy, garment vertices nearer the skin than this (as their proxy triangle's
    distances say) are searched and pushed out of the body at the end of the frame (5 mm:
    ε_c +150 % on validation)."""

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            kind = get_type_hints(RuntimeConfig)[item.name]
            if kind is bool:
                if not isinstance(value, bool):
                    raise ParameterError(f"runtime {item.name}={value!r} must be true or false")
            elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ParameterError(f"runtime {item.name}={value!r} must be a finite number")
            elif kind is int and not isinstance(value, int):
                raise ParameterError(f"runtime {item.name}={value!r} must be a whole number")
        for name in ("follow", "loose_follow"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ParameterError(f"runtime {name}={getattr(self, name)!r} must be in (0, 1]")
        if not 0.0 <= self.carry_lag < 1.0:
            raise ParameterError(f"runtime carry_lag={self.carry_lag!r} must be in [0, 1)")
        if not 0.0 <= self.follow_near < self.follow_far:
            raise ParameterError(f"runtime follow_near={self.follow_near!r} and follow_far={self.follow_far!r} "
                                 "must satisfy 0 <= follow_near < follow_far")
        for name in ("contact_margin", "query_distance", "round_query_distance", "plane_reach",
                     "projection_anchor", "proxy_push_reach"):
            if getattr(self, name) <= 0:
                raise ParameterError(f"runtime {name}={getattr(self, name)!r} must be > 0")
        if self.round_search_gap != 0 and self.round_search_gap <= self.contact_margin:
            raise ParameterError(f"runtime round_search_gap={self.round_search_gap!r} must be 0 (off) or more than "
                                 f"contact_margin={self.contact_margin!r} (a vertex nearer than the margin must be "
                                 "searched and pushed)")
        if self.uv_resolution != 0 and not 8 <= self.uv_resolution <= MAX_UV_RESOLUTION:
            raise ParameterError(f"runtime uv_resolution={self.uv_resolution!r} must be 0 (the model's) or in "
                                 f"[8, {MAX_UV_RESOLUTION}]")
        if not 1 <= self.push_rounds <= MAX_ROUNDS:
            raise ParameterError(f"runtime push_rounds={self.push_rounds!r} must be in [1, {MAX_ROUNDS}]")
        for name, most in (("contact_rounds", MAX_ROUNDS), ("projection_iterations", MAX_ITERATIONS),
                           ("proxy_sweeps", MAX_ITERATIONS)):
            if not 0 <= getattr(self, name) <= most:
                raise ParameterError(f"runtime {name}={getattr(self, name)!r} must be in [0, {most}]")
        if self.proxy_vertices != 0 and not MIN_PROXY_VERTICES <= self.proxy_vertices:
            raise ParameterError(f"runtime proxy_vertices={self.proxy_vertices!r} must be 0 (no proxy) or at least "
                                 f"{MIN_PROXY_VERTICES}")
        if not 0.0 < self.proxy_relaxation <= 2.0:
            raise ParameterError(f"runtime proxy_relaxation={self.proxy_relaxation!r} must be in (0, 2]")
        if self.projection_stretch < 0:
            raise ParameterError(f"runtime projection_stretch={self.projection_stretch!r} must be >= 0")
        if not -1.0 <= self.untangle_cosine <= 1.0:
            raise ParameterError(f"runtime untangle_cosine={self.untangle_cosine!r} must be in [-1, 1]")
        if not 0.0 <= self.projection_compression < 1.0:
            raise ParameterError(f"runtime projection_compression={self.projection_compression!r} must be in [0, 1)")

    @property
    def follows(self) -> bool:
        """Whether the garment is carried from the last frame at all (either share below 1)."""
        return self.follow < 1.0 or self.loose_follow < 1.0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "runtime config") -> "RuntimeConfig":
        """The config of a stored dict (a checkpoint's); keys it lacks take the defaults."""
        known = {item.name for item in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ParameterError(f"{source}: unknown runtime setting(s) {unknown}; known: {', '.join(sorted(known))}")
        return cls(**values)

    def with_overrides(self, text: str | None) -> "RuntimeConfig":
        """This config with ``key=value,...`` (``--runtime``) applied: numbers, ``true``/``false``."""
        return replace(self, **parse_overrides(text))


def parse_overrides(text: str | dict[str, Any] | None) -> dict[str, Any]:
    """``--runtime key=value,...`` (or such a dict) as {setting: value}, checked against the
    fields' types and ranges (over the defaults), so a bad value fails before any work starts."""
    if isinstance(text, dict):
        text = ",".join(f"{key}={value}" for key, value in text.items())
    if text is None or not text.strip():
        return {}
    hints = get_type_hints(RuntimeConfig)
    values: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, raw = (s.strip() for s in item.partition("="))
        if not sep:
            raise ParameterError(f"--runtime: expected key=value, got {item!r}")
        if key not in hints:
            raise ParameterError(f"--runtime: unknown setting {key!r}; known: {', '.join(hints)}")
        if key in values:
            raise ParameterError(f"--runtime: {key!r} given twice")
        values[key] = _parse_value(key, raw, hints[key])
    try:
        replace(RuntimeConfig(), **values)
    except ParameterError as error:
        raise ParameterError(f"--runtime: {error}") from None
    return values


def _parse_value(key: str, raw: str, kind) -> bool | int | float:
    if kind is bool:
        if raw.lower() in ("true", "1", "yes", "on"):
            return True
        if raw.lower() in ("false", "0", "no", "off"):
            return False
        raise ParameterError(f"--runtime: {key}={raw!r} must be true or false")
    try:
        number = float(raw)
    except ValueError:
        raise ParameterError(f"--runtime: {key}={raw!r} is not a number") from None
    if kind is int:
        if not number.is_integer():
            raise ParameterError(f"--runtime: {key}={raw!r} must be a whole number")
        return int(number)
    return number


RAW = {"follow": 1.0, "loose_follow": 1.0, "contact": False, "conv_mlp": True}
"""The settings that turn the runtime into Module A alone (the method ``hyperbones-raw``): both
of its stages, nothing around them."""
