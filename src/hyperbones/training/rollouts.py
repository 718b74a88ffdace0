"""A's targets in phase 2: whole rollouts of the teacher (Module C), kept and refreshed.

Each rollout is C run without gradient from the LBS start (after its settling step) over a
training clip on a random identity, as ``hyperbones simulate --method teacher`` runs it, so
A learns C's lag, swing and settling along a whole motion, not only a few steps from an LBS
pose. Every ``refresh_every`` steps the oldest rollout is replaced by one of the current C
(or, with a bank, by a saved one: ``RolloutCache``).

A rollout is kept only if, over its last third, the garment stays near where it started,
skinned along (``drift``: its mean height above it within ``max_rise``, its RMS distance
within ``max_gap``; a draped start is skinned from its drape, not from the rest shape, which a
draped long skirt hangs ~14 cm RMS from), and if few of its vertex-frames above the hips came
off the body (``detachment``: at most ``max_detached_pct``); the teacher lets some garments
creep up the body or slide off, and such a rollout would teach A a wrong place for the
garment. A refused one is replaced by a new draw (up to ``MAX_DRAWS`` in all); a refused bank
file is skipped.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from hyperbones.body.anny_body import PosedBody
from hyperbones.body.shape import BodyShape
from hyperbones.devices import cpu_has_bfloat16
from hyperbones.errors import InputFileError, ParameterError
from hyperbones.geometry.search import signed_distances_along
from hyperbones.io_utils import atomic_path, load_versioned
from hyperbones.models.teacher import Autocast, Teacher
from hyperbones.physics.material import Material
from hyperbones.physics.metrics import detached_pct
from hyperbones.runtime.identity import IdentityGeometry
from hyperbones.training.config import JointConfig
from hyperbones.training.episode import Identity as PhysicsIdentity

if TYPE_CHECKING:
    from hyperbones.training.data import TeacherData


@dataclass
class TeacherRollout:
    """C along one clip on one identity (T frames).

    physics: the identity's cloth (rest state, body, carried garment).
    geometry: its virtual bones, UV maps and canonical graph (what Module B reads).
    joint_rotations: (T,31,3,3); root_translation: (T,3); skinning: (T,31,4,4);
    body_vertices: (T,Vb,3); positions: (T,V,3) C's garment; edges: (E,2) the garment's
    edges; step: when it was made; latents: filled in by a trainer whose trunk is frozen.
    """

    physics: PhysicsIdentity
    geometry: IdentityGeometry
    joint_rotations: torch.Tensor
    root_translation: torch.Tensor
    skinning: torch.Tensor
    body_vertices: torch.Tensor
    positions: torch.Tensor
    edges: torch.Tensor
    motion: str
    step: int
    latents: torch.Tensor | None = None  # (V,latent) a frozen trunk's output on geometry.graph, once computed
    source: str = ""  # the bank file it was loaded from

    @property
    def num_frames(self) -> int:
        return self.positions.shape[0]


MAX_DRAWS = 5  # rollouts drawn per refresh before the last one is kept whatever its drift


@dataclass
class SimulatedRollout:
    """A teacher rollout before it enters the cache: the identity, the clip window's name,
    joint rotations (T,31,3,3) and root path (T,3), the body posed along them, C's garment
    (T,V,3), and its ``drift`` (rise, gap in m)."""

    identity: PhysicsIdentity
    motion: str
    joint_rotations: torch.Tensor
    root: torch.Tensor
    posed: PosedBody
    positions: torch.Tensor
    rise: float
    gap: float
    detached: float = 0.0  # % of vertex-frames come off the body (``detachment``)
    identity_seconds: float = 0.0  # wall time drawing the identity (its drape included, when draped)
    rollout_seconds: float = 0.0  # wall time of C's rollout and its checks
    identity_cpu_seconds: float = 0.0  # the same in this process's CPU time (blind to other jobs and pauses)
    rollout_cpu_seconds: float = 0.0


def drift(positions: torch.Tensor, skinned: torch.Tensor) -> tuple[float, float]:
    """(T,V,3) C's garment and (T,V,3) the same garment skinned -> over the last third of
    the frames, the mean height of C's garment above the skinned one (m) and the mean RMS
    distance between them (m)."""
    tail = slice(positions.shape[0] - max(1, positions.shape[0] // 3), None)
    offset = positions[tail] - skinned[tail]
    return float(offset[..., 2].mean()), float(offset.square().sum(-1).mean(-1).sqrt().mean())


def signed_distances_from_start(search, positions: torch.Tensor, bodies: torch.Tensor, start: torch.Tensor,
                                canonical_body: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(T,N) signed distances of a rollout's garment ``positions`` (T,N,3) to its posed ``bodies``
    (T,Nb,3), and (N,) those of its ``start`` (the garment it began from) to the ``canonical_body``
    (Nb,3), with ``search`` (``geometry.search.signed_distances_along``); inf beyond its range."""
    reference = signed_distances_along(search, start[None], canonical_body[None])[0]
    return signed_distances_along(search, positions, bodies), reference


def detached_above_hips(distances: torch.Tensor, reference: torch.Tensor, start: torch.Tensor,
                        hips_height: float) -> float:
    """``detached_pct`` of (T,V) ``distances`` against (V,) ``reference``, over the vertices whose
    ``start`` (V,3) lies above the body's hips head (``hips_height``, m, canonical).

    Above the hips a garment rests on the body, so cloth far from the skin there has come off
    (an open shirt streaming behind a walk like a cape); below, a skirt's hem swings away from
    the legs as it should (the teacher's long skirt on the walk: 27 % of all its vertex-frames
    more than 10 cm out, 1.3 % of those above the hips). 0 when no vertex lies above the hips.
    """
    upper = start[:, 2].to(distances.device) > hips_height
    return detached_pct(distances[:, upper], reference[upper]) if bool(upper.any()) else 0.0


def refusal_reasons(config: JointConfig, rise: float, gap: float, detached: float) -> list[str]:
    """The config's checks a rollout with this ``drift`` and ``detached`` share (%) fails: any of
    "rise", "gap", "detached" (none: it passes)."""
    return [name for name, value, limit in (("rise", rise, config.max_rise), ("gap", gap, config.max_gap),
                                            ("detached", detached, config.max_detached_pct))
            if limit > 0 and value > limit]


def refused(config: JointConfig, rise: float, gap: float, detached: float) -> bool:
    """Whether a rollout with this ``drift`` and ``detached`` share (%) fails the config's checks."""
    return bool(refusal_reasons(config, rise, gap, detached))


class RolloutCache:
    """Up to ``config.cache_size`` teacher rollouts; ``sample`` draws a (rollout, frame) pair.

    With ``config.bank`` (a folder of rollouts saved by ``hyperbones rollouts``), a refresh
    loads a saved rollout instead of simulating one, so the rollouts A learns from can be
    made beforehand, by other processes, and kept across runs.
    """

    def __init__(self, data: TeacherData, config: JointConfig, num_bones: int, uv_resolution: int,
                 device: torch.device, settle_dt: float):
        self.data, self.config = data, config
        self.num_bones, self.uv_resolution = num_bones, uv_resolution
        self.device, self.settle_dt = device, settle_dt
        self.rollouts: list[TeacherRollout] = []
        self.refused = 0  # rollouts not kept for their drift or detachment
        self.file_detachment: dict[str, float] = {}  # bank file -> its ``detachment``, measured once
        self._search = None  # Warp's body search for ``detachment``, made on first use

    def simulate(self, teacher: Teacher,
                 on_draw: Callable[[SimulatedRollout], None] | None = None) -> SimulatedRollout:
        """C over a random clip window on a random identity, redrawn while its ``drift`` or
        ``detachment`` fails the config's checks (the last of ``MAX_DRAWS`` draws is kept
        whatever it is). ``on_draw`` sees every draw, refused ones included, as it is made."""
        def draw_once() -> SimulatedRollout:
            draw = self._draw(teacher)
            if on_draw is not None:
                on_draw(draw)
            return draw

        draw, draws = draw_once(), 1
        while draws < MAX_DRAWS and refused(self.config, draw.rise, draw.gap, draw.detached):
            self.refused += 1
            draw, draws = draw_once(), draws + 1
        return draw

    @property
    def refused_files(self) -> set[str]:
        """Bank files refused for their ``detachment`` (not loaded again)."""
        return {path for path, detached in self.file_detachment.items() if refused(self.config, 0.0, 0.0, detached)}

    def detachment(self, identity: PhysicsIdentity, positions: torch.Tensor, bodies: torch.Tensor) -> float:
        """% of the vertex-frames of C's garment ``positions`` (T,V,3) on ``identity``'s posed
        ``bodies`` (T,Vb,3), above the hips, more than 10 cm farther from the skin than its start
        was on the canonical body (``detached_above_hips``); 0 without the check
        (``max_detached_pct`` 0)."""
        if self.config.max_detached_pct <= 0:
            return 0.0
        if self._search is None:
            from hyperbones.geometry.proximity import BodyProximity  # Warp

            self._search = BodyProximity(identity.body.faces)
        start, body = identity.garment.vertices, identity.body
        distances, reference = signed_distances_from_start(self._search, positions, bodies, start, body.rest_vertices)
        return detached_above_hips(distances, reference, start, float(body.rest_joint_positions[0, 2]))

    def make(self, teacher: Teacher, step: int) -> TeacherRollout:
        """A new rollout of ``teacher`` that passes the drift and detachment checks (the last of ``MAX_DRAWS``
        otherwise)."""
        draw = self.simulate(teacher)
        return self.assemble(draw.identity, draw.motion, draw.joint_rotations, draw.root, draw.positions, step,
                             posed=draw.posed)

    def _draw(self, teacher: Teacher) -> SimulatedRollout:
        """One rollout of ``teacher`` (put in eval mode for it: its input statistics stay as
        they are) and its ``drift``."""
        from hyperbones.runtime.teacher_method import TeacherMethod  # Warp's search and Anny's body

        data = self.data
        started, started_cpu = time.perf_counter(), time.process_time()
        identity = data.sample_identity()
        drawn, drawn_cpu = time.perf_counter(), time.process_time()
        at_end = data.random.random() < self.config.end_fraction
        window, root = data.sample_window(self.config.rollout_frames, identity, at_end=at_end)
        posed = identity.body.pose(window.joint_rotations, root)
        garment = identity.garment
        was_training = teacher.training
        teacher.eval()
        try:
            method = TeacherMethod(garment, identity.body, garment.vertices, garment.material, model=teacher,
                                   settle_dt=self.settle_dt, device=str(self.device))
            positions = method.run(posed)
        finally:
            teacher.train(was_training)
        # Drift from where it started: the drape, skinned along, for a draped start.
        rise, gap = drift(positions, identity.skin(posed.skinning_transforms, garment.vertices))
        detached = self.detachment(identity, positions, posed.vertices)
        return SimulatedRollout(identity, window.name, window.joint_rotations, root, posed, positions, rise, gap,
                                detached, drawn - started, time.perf_counter() - drawn, drawn_cpu - started_cpu,
                                time.process_time() - drawn_cpu)

    def assemble(self, identity: PhysicsIdentity, motion: str, joint_rotations: torch.Tensor, root: torch.Tensor,
                 positions: torch.Tensor, step: int = 0, posed: PosedBody | None = None,
                 source: str = "") -> TeacherRollout:
        """A cache entry: the identity's geometry (bones, UV maps, graph) and the posed body
        added (``posed``: already posed along ``joint_rotations``, ``root``)."""
        if posed is None:
            posed = identity.body.pose(joint_rotations, root)
        garment = identity.garment
        geometry = IdentityGeometry.build(garment, identity.body, self.num_bones, self.uv_resolution, self.device,
                                          name=identity.name, rest_vertices=identity.rest.rest_vertices)
        return TeacherRollout(identity, geometry, joint_rotations, root, posed.skinning_transforms, posed.vertices,
                              positions.float(), garment.edges(), motion, step, source=source)

    def load(self, path: str | Path, step: int = 0) -> TeacherRollout:
        """A rollout saved by ``save_rollout``, rebuilt on this config's garments as it started
        (draped or carried, whatever ``data.drape`` says: a bank may hold both). A draped one
        starts from the garment saved with it; files from before that was saved (2026-11-30)
        are draped again (cached on disk)."""
        record = load_rollout(path)
        draped = record.get("draped", False)  # banks from before the flag are undraped
        try:
            identity = self.data.identity_for(record["template"], record["resolution"], BodyShape(**record["shape"]),
                                              Material(**record["material"]), drape=draped, start=record.get("start"))
        except ParameterError as error:
            raise InputFileError(path, str(error)) from None
        if identity.rest.rest_vertices.shape[0] != record["positions"].shape[1]:
            raise InputFileError(path, f"{record['positions'].shape[1]} garment vertices, but {record['template']} at "
                                       f"{record['resolution']} has {identity.rest.rest_vertices.shape[0]} here")
        return self.assemble(identity, record["motion"], record["joint_rotations"], record["root_translation"],
                             record["positions"], step, source=str(path))

    def refresh(self, teacher: Teacher, step: int) -> TeacherRollout:
        """Add a rollout (from the bank when the config names one and it holds a rollout not
        in the cache and not refused for its ``detachment``, else a new one), dropping the
        oldest when the cache is full."""
        rollout = None
        if self.config.bank:
            cached = {r.source for r in self.rollouts} | self.refused_files
            unused = [path for path in bank_files(self.config.bank) if str(path) not in cached]
            while unused and rollout is None:
                rollout = self.load(unused.pop(self.data.random.randrange(len(unused))), step)
                if rollout.source not in self.file_detachment:  # its drift was checked when it was made
                    self.file_detachment[rollout.source] = self.detachment(rollout.physics, rollout.positions,
                                                                           rollout.body_vertices)
                if refused(self.config, 0.0, 0.0, self.file_detachment[rollout.source]):
                    self.refused += 1
                    rollout = None
        if rollout is None:
            rollout = self.make(teacher, step)
        return self.admit(rollout)

    def admit(self, rollout: TeacherRollout) -> TeacherRollout:
        """Put ``rollout`` in the cache, dropping the oldest when it is full."""
        if len(self.rollouts) >= self.config.cache_size:
            oldest = min(range(len(self.rollouts)), key=lambda i: self.rollouts[i].step)
            self.rollouts.pop(oldest)
        self.rollouts.append(rollout)
        return rollout

    def sample(self) -> tuple[TeacherRollout, int]:
        """A cached rollout and a frame t >= 2 of it (A's window repeats frame 0 before the start)."""
        rollout = self.data.random.choice(self.rollouts)
        return rollout, self.data.random.randrange(2, rollout.num_frames)

    def sample_frames(self, count: int, per_rollout: int = 1) -> list[tuple[TeacherRollout, int]]:
        """``count`` (rollout, t) pairs: ``count // per_rollout`` cached rollouts drawn (``sample``),
        ``per_rollout`` frames of each, a rollout's pairs next to each other."""
        samples = []
        for _ in range(count // per_rollout):
            rollout, t = self.sample()
            samples += [(rollout, t)] + [(rollout, self.data.random.randrange(2, rollout.num_frames))
                                         for _ in range(per_rollout - 1)]
        return samples


BANK_VERSION = 1


def bank_files(folder: str | Path) -> list[Path]:
    """The saved rollouts in a bank folder (sorted; none when it does not exist yet)."""
    return sorted(Path(folder).glob("rollout-*.pt"))


def save_rollout(path: str | Path, identity: PhysicsIdentity, motion: str, joint_rotations: torch.Tensor,
                 root: torch.Tensor, positions: torch.Tensor, network_dtype: str = "float32") -> Path:
    """Write one rollout compactly (atomically): what rebuilds its identity (template,
    resolution, body shape, fabric, whether it was draped, and the draped garment it started
    from, so that loading it drapes nothing), the clip window and C's garment in half
    precision (T,V,3): ~1.7 MB for 150 frames of 1550 vertices. The body is posed again on
    loading. network_dtype: the precision C's network ran in (a record of how the rollout was
    made; banks from before it are float32)."""
    if identity.resolution is None:
        raise ParameterError("only an identity sampled by TeacherData (with its template resolution) can be saved")
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"version": BANK_VERSION, "template": identity.name, "resolution": identity.resolution,
                    "shape": identity.body.shape.as_dict(), "material": identity.garment.material.as_dict(),
                    "draped": identity.draped, "motion": motion, "joint_rotations": joint_rotations.float(),
                    "root_translation": root.float(), "positions": positions.half(),
                    "start": identity.garment.vertices.float() if identity.draped else None,
                    "network_dtype": network_dtype}, tmp)
    return path


def load_rollout(path: str | Path) -> dict:
    """A rollout written by ``save_rollout`` (its fields as saved)."""
    return load_versioned(path, "saved rollout", BANK_VERSION)


def generate_bank(config, folder: str | Path, count: int, seed: int = 0, progress: bool = True,
                  compile_teacher: bool = False, bfloat16: bool = False) -> list[Path]:
    """Simulate ``count`` drift- and detachment-checked rollouts of the config's teacher
    (``train.init_from``) into ``folder`` as ``rollout-s<seed>-<index>.pt``. Run again with the
    same seed, it goes on after the files already there (with fresh draws), so several
    processes with different seeds (and data settings, such as ``data.drape``), or one
    process over several sessions, fill one bank. compile_teacher: run the teacher's network
    through ``compiled_for_inference`` (a long bank on the CPU: ~1.2-1.35x its speed there).
    bfloat16: run the teacher's network under ``Autocast`` (its inputs, the integration, the
    contact and the strain limiting stay float32), as the GPU job's rollouts do with
    ``train.bfloat16``: faster where the processor has bfloat16 units, and its rollouts differ
    from float32's no more than two float32 rollouts differ after rounding changes
    (docs/experiments/2026-11-30-bfloat16-bank.md)."""
    from tqdm import tqdm

    from hyperbones.models.loading import teacher_from_checkpoint
    from hyperbones.training.data import TeacherData

    if count < 1:
        raise ParameterError("--count must be at least 1")
    if not config.train.init_from:
        raise ParameterError("the config names no teacher to roll out (train.init_from)")
    folder = Path(folder)
    first = len(list(folder.glob(f"rollout-s{seed}-*.pt"))) if folder.exists() else 0
    teacher, _ = teacher_from_checkpoint(config.train.init_from)
    network_dtype = "bfloat16" if bfloat16 else "float32"
    if bfloat16:
        if not cpu_has_bfloat16():
            warnings.warn("--bfloat16: this CPU lacks bfloat16 units, so the teacher runs slower than in float32 "
                          "here", stacklevel=2)
        teacher = Autocast(teacher)
    if compile_teacher:
        teacher = compiled_for_inference(teacher)
    data = TeacherData(config.data, seed=seed * 1_000_003 + first,
                       progress=(lambda text: print(f"preparing {text}", flush=True)) if progress else None)
    cache = RolloutCache(data, config.joint, config.runtime.num_bones, config.runtime.uv_resolution,
                         torch.device("cpu"), config.data.settle_dt)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    with torch.no_grad():
        for index in tqdm(range(first, first + count), desc="rollouts", disable=not progress, unit="rollout"):
            draws: list[SimulatedRollout] = []
            kept = cache.simulate(teacher, on_draw=draws.append)
            path = save_rollout(folder / f"rollout-s{seed}-{index:05d}.pt", kept.identity, kept.motion,
                                kept.joint_rotations, kept.root, kept.positions, network_dtype)
            written.append(path)
            log_draws(folder / DRAW_LOG, [draw_record(draw, config.joint, seed, index, network_dtype,
                                                      path.name if draw is kept else None) for draw in draws])
    print(f"wrote {len(written)} rollout{'' if len(written) == 1 else 's'} to {folder} ({cache.refused} draws "
          f"refused for drift or detachment; every draw is listed in {DRAW_LOG} there)")
    return written


DRAW_LOG = "draws.jsonl"  # a bank's record of every draw ``generate_bank`` made, one JSON object a line


def draw_record(draw: SimulatedRollout, config: JointConfig, seed: int, index: int, network_dtype: str,
                file: str | None) -> dict:
    """One line of a bank's draw log: what was drawn, its checks (``refused_for``: the ones it
    failed), its cost (s, wall and this process's CPU time), and the file it was saved as (None:
    not saved). A draw that failed
    is still saved when it was the last of ``MAX_DRAWS``."""
    identity = draw.identity
    return {"seed": seed, "index": index, "file": file, "template": identity.name, "vertices": identity.resolution,
            "draped": identity.draped, "motion": draw.motion, "frames": int(draw.positions.shape[0]),
            "rise_m": round(draw.rise, 5), "gap_m": round(draw.gap, 5), "detached_pct": round(draw.detached, 3),
            "refused_for": refusal_reasons(config, draw.rise, draw.gap, draw.detached),
            "identity_s": round(draw.identity_seconds, 2), "rollout_s": round(draw.rollout_seconds, 2),
            "identity_cpu_s": round(draw.identity_cpu_seconds, 2), "rollout_cpu_s": round(draw.rollout_cpu_seconds, 2),
            "network_dtype": network_dtype, "made": time.strftime("%Y-%m-%dT%H:%M:%S")}


def log_draws(path: Path, records: list[dict]) -> None:
    """Append ``records`` to a draw log in one write. A process stopped mid-write leaves at most
    its last line cut short: ``read_draw_log`` skips it, and the next append drops it first."""
    text = "".join(json.dumps(record) + "\n" for record in records).encode("utf-8")
    with open(path, "ab+") as log:
        end = log.seek(0, os.SEEK_END)
        if end:
            log.seek(end - 1)
            if log.read(1) != b"\n":
                log.seek(0)
                log.truncate(log.read().rfind(b"\n") + 1)
        log.write(text)


def read_draw_log(path: str | Path) -> list[dict]:
    """The records of a bank's draw log (``log_draws``); a last line cut short is left out, any
    other line that is not JSON is an error."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "no draw log (hyperbones rollouts writes one into its bank since 2026-11-30)")
    lines = path.read_text(encoding="utf-8").splitlines()
    records = []
    for number, line in enumerate(lines, start=1):
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            if number < len(lines):
                raise InputFileError(path, f"line {number} is not a JSON record") from None
    return records


def compiled_for_inference(teacher: Teacher) -> Teacher:
    """``teacher`` through ``torch.compile`` (inductor, shapes dynamic: one compilation serves
    every garment size), for rollouts without gradients. On one CPU thread its MeshGraphNet runs
    1.2-1.35x faster after 10-30 s of compiling, agreeing to float32 rounding
    (docs/experiments/2026-11-29-strain-sweeps.md); needs a C++ compiler, so it is asked for
    (``hyperbones rollouts --compile``), never assumed."""
    import os
    import shutil

    if not any(shutil.which(name) for name in (os.environ.get("CXX", ""), "g++", "clang++", "c++") if name):
        raise ParameterError("--compile needs a C++ compiler on PATH (g++, clang++ or $CXX); none was found")
    return torch.compile(teacher, dynamic=True)
