"""The typed training configuration, read from a TOML file and saved into every checkpoint.

A teacher config has three tables, ``[model]``, ``[data]`` and ``[train]``, with the fields
of ``TrunkConfig``, ``DataConfig`` and ``TrainConfig``. A HyperBones (joint, phase 2) config
adds ``[runtime]`` (``ModuleAConfig``) and ``[joint]`` (``JointConfig``); ``load_config``
tells them apart by the ``[joint]`` table. Anything left out takes the default below, so a
config file states only what differs; ``apply_overrides`` changes any field from the command
line (``--set section.key=value``). Unknown keys and wrongly typed values are one-line errors
that name the file or the option. Why the shipped configs differ from the defaults, and what
what their runs found: ``docs/experiments/``.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar, get_args, get_origin, get_type_hints

from hyperbones.errors import InputFileError, ParameterError
from hyperbones.garment.templates import TEMPLATES
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import TrunkConfig

EVAL_BODIES = ("gender=0.3,age=0.6,muscle=0.7,weight=0.3,height=0.6,proportions=0.4",
               "gender=0.8,age=0.4,muscle=0.3,weight=0.8,height=0.3,proportions=0.6")


@dataclass(frozen=True)
class DataConfig:
    """What the teacher trains on, and what is held out: a validation set (training clips ×
    unseen bodies) for choices made after training, a test set (unseen clips × unseen bodies)."""

    templates: tuple[str, ...] = tuple(TEMPLATES)
    """Garment templates trained on, each made on the default body and carried to every sampled body."""
    resolutions: tuple[int, ...] = (1500, 2500)
    """Vertex counts each template is trained at, so the model is not tied to one mesh density."""
    mocap_dir: str = "../shared/data/mocap/cmu"
    """Folder of the CMU BVH clips the clip lists name (relative to the folder the command runs in)."""
    train_clips: tuple[str, ...] = ("01_01", "02_01", "02_03", "05_06", "111_10", "16_07", "16_27", "69_53", "74_06")
    """CMU clips (file stems under ``mocap_dir``) that training samples motions from."""
    test_clips: tuple[str, ...] = ("16_21", "16_35", "143_06")
    """Held-out CMU clips: never sampled in training nor used to choose anything; the final numbers only."""
    validation_clips: tuple[str, ...] = ("16_07", "02_03")
    """Training clips (seen by training, a subset of ``train_clips``) that after-training choices are
    made on: the validation set is these clips × ``validation_bodies``, bodies unseen in training."""
    source_fps: dict[str, float] = field(default_factory=lambda: {"74_06": 60.0, "143_06": 60.0})
    """Real capture rate of clips whose BVH header says otherwise (CMU 74_06 and 143_06: 60 fps, headers 120)."""
    builtins: tuple[str, ...] = ("walk", "run", "jump", "turn", "idle", "arm-swing", "sit")
    """Built-in motions (``hyperbones motion``) trained on besides the clips."""
    test_bodies: tuple[str, ...] = EVAL_BODIES
    """Held-out body shapes ("key=value,..." over the six phenotype values), kept out of training."""
    validation_bodies: tuple[str, ...] = EVAL_BODIES
    """Body shapes of the validation set; they coincide with ``test_bodies`` (every after-training
    choice so far was made on them), so validation and test share bodies but never clips."""
    test_body_margin: float = 0.25
    """Least L2 distance (over the six phenotype values) of a sampled training body from each test body."""
    hold_seconds: float = 1.5
    """Stillness appended to every training clip, so the model learns how cloth settles after the body stops."""
    default_material_fraction: float = 0.5
    """Share of episodes with HOOD's default fabric; the others draw μ, λ, k_b, ρ over HOOD's ranges."""
    start_noise: float = 0.001
    """Std (m) of the Gaussian noise added to an episode's LBS start."""
    settle_dt: float = 1.0 / 3.0
    """Length (s) of an episode's first step, taken with the body held still, so the garment settles on it."""
    airborne_fraction: float = 0.0
    """Share of episodes whose root gets free-fall hops (``training.data.ballistic_hops``): the clips
    hold too little flight to learn that cloth falls at g once the body drops away from it."""
    hop_speeds: tuple[float, float] = (0.8, 2.2)
    """Range (m/s) the hops' launch speeds are drawn from."""
    drape: bool = False
    """Settle each carried garment on its body (``garment.drape``, cached) before use, as ``simulate``
    and ``eval`` do: rollouts, Module B's graph and the bones' places start from the drape. Off: the
    carried garment, which a rollout's first (settling) step drapes. The physics rest shape and the
    bones' skinning weights come from the carried garment either way."""

    def __post_init__(self) -> None:
        seen_by_test = sorted(set(self.validation_clips) & set(self.test_clips))
        if seen_by_test:
            raise ParameterError(f"data.validation_clips {seen_by_test} are test clips; "
                                 "validation must not see the test set")
        # A config that trains on built-in motions alone (train_clips empty) has no clip to validate on.
        untrained = sorted(set(self.validation_clips) - set(self.train_clips))
        if self.train_clips and untrained:
            raise ParameterError(f"data.validation_clips {untrained} are not in data.train_clips; "
                                 "validation clips are training clips (set data.validation_clips too)")


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation (HOOD's by default: Adam, grad-norm clip, collision-weight ramp, episodes 1 → 5 steps)."""

    steps: int = 100_000
    """Optimiser steps of the run."""
    learning_rate: float = 5e-5
    """Adam's learning rate (HOOD's)."""
    learning_rate_halve_at: tuple[int, ...] = ()
    """Steps at which the learning rate halves (a staircase decay); empty: constant."""
    grad_clip: float = 1.0
    """Gradient-norm clip of each step (HOOD's)."""
    collision_weight_start: float = 5e3
    """Weight of the collision term at step 0, where HOOD's ramp starts."""
    collision_weight_end: float = 5e5
    """Weight of the collision term once the ramp is over."""
    collision_ramp_steps: int = 50_000
    """Steps of the geometric ramp from the start weight to the end weight; 0: the end weight throughout."""
    rollout_start: int = 1
    """Simulation steps per episode at step 0."""
    rollout_max: int = 5
    """Simulation steps per episode once the ramp is over."""
    rollout_ramp_steps: int = 20_000
    """Steps over which episodes grow from ``rollout_start`` to ``rollout_max`` (0: ``rollout_max`` throughout),
    so the model meets, and learns to pull back from, the states its own rollouts drift into."""
    checkpoint_every: int = 250
    """Steps between checkpoints (``checkpoint.pt`` and ``optimizer.pt`` in the run folder; ``--resume`` reads them)."""
    log_every: int = 10
    """Steps between TensorBoard log entries."""
    seed: int = 0
    """Seed of the initial weights and the episode draws (each DDP process adds its rank)."""
    device: str = "auto"
    """"auto" (CUDA when present), "cpu" or "cuda[:N]"."""
    init_from: str = ""
    """Checkpoint a new run starts from (relative to the folder the command runs in), at step 0 with a fresh
    optimiser: its teacher weights and input statistics (a joint checkpoint gives its Module C; a joint run
    from a joint checkpoint also takes Modules A and B: fine-tuning). Its model section must match. Empty: random."""
    bfloat16: bool = False
    """Run the teacher's network in bfloat16 autocast (``models.teacher.Autocast``); the graph's features,
    the loss, the integration and the weights stay float32. Its forward and backward are ~1.7× faster on
    a CPU with AVX512-BF16 and use a GPU's tensor cores (docs/experiments/*-training-pack.md)."""
    ema_decay: float = 0.999
    """Per-step decay of the weights' moving average that checkpoints also keep and inference loads (single
    steps of the one-step physics loss move the weights noisily; the average rolls out more steadily); 0: none."""


@dataclass(frozen=True)
class TeacherTrainingConfig:
    """A teacher (phase 1) run: the trunk's size, the data and the optimisation."""

    model: TrunkConfig = TrunkConfig()
    data: DataConfig = DataConfig()
    train: TrainConfig = TrainConfig()

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "config") -> "TeacherTrainingConfig":
        """From a file's tables or a checkpoint's saved dict; keys it lacks (older checkpoints) take the defaults."""
        hints = get_type_hints(cls)
        unknown = set(values) - set(hints)
        if unknown:
            raise InputFileError(source, f"unknown section(s) {sorted(unknown)}; expected {sorted(hints)}")
        return cls(**{name: _build(hints[name], values.get(name, {}), name, source) for name in hints})

    @classmethod
    def load(cls, path: str | Path) -> "TeacherTrainingConfig":
        config = load_config(path)
        if not isinstance(config, cls):
            raise InputFileError(path, f"expected a {cls.__name__.replace('TrainingConfig', '').lower()} config")
        return config


@dataclass(frozen=True)
class JointConfig:
    """Phase 2 (paper Sec. 3.5): C keeps training on L_phys while A learns C's rollouts.
    A phase-2 run starts from a phase-1 teacher through ``train.init_from``."""

    cache_size: int = 16
    """Whole teacher rollouts held at a time; C's states along them (no gradient) are A's targets."""
    rollout_frames: int = 150
    """Frames of each cached rollout, from the LBS start through the clip."""
    refresh_every: int = 200
    """Steps between replacing the oldest cached rollout by a new one, so A meets many identities and
    its targets improve with C."""
    end_fraction: float = 0.3
    """Share of rollouts that end where their clip ends (in its hold), so A sees the cloth settle."""
    frames_per_step: int = 1
    """Cached frames A is trained on per optimiser step (one batch through Modules B and A)."""
    frames_per_rollout: int = 1
    """Of those, frames drawn from each drawn rollout (it must divide ``frames_per_step``): Module B, the bones'
    posing and A's skinning and UV maps then run once per rollout, so a GPU step of many frames costs per
    rollout, not per frame. 1: every frame from a rollout drawn for it."""
    position_scale: float = 1e4
    """Factor on L_MSE and L_lap (errors in m²); 1e4 takes them in cm², so a centimetre of error
    weighs about as much as a joule of the physics terms."""
    laplacian_weight: float = 0.1
    """λ_lap on the Laplacian of A's error (the paper's; 0: the ablation)."""
    edge_weight: float = 0.0
    """λ_edge on the error of A's edge lengths against C's (the mean over a frame's edges of the squared
    difference of their lengths, scaled as L_MSE). Not in the paper: it aims at A's stretch itself, where
    L_MSE and L_lap see it only as millimetres among centimetres (docs/experiments/*edge-length-loss.md). 0: off."""
    interpenetration_weight: float = 0.1
    """λ_interp on A's interpenetration term (the paper's; 0: the ablation)."""
    interpenetration_epsilon: float = 0.003
    """ε (m) of the interpenetration term: A's vertices nearer the body than this are penalised."""
    physics_on_runtime: bool = True
    """Also put L_phys's terms (stretching, bending, collision, with its weights) on A's output."""
    trunk_from_runtime: bool = False
    """A's loss also trains the shared trunk through Module B (the paper's joint training). Off: B's heads
    alone learn from it, so L_3D, far larger than C's physics terms, does not take over the trunk's gradient clip."""
    train_teacher: bool = True
    """Off: C and the shared trunk stay frozen (a finished phase-1 teacher), a step is A's terms alone and each
    cached rollout's trunk latents are computed once; the CPU setting, where C's own step costs the most."""
    max_rise: float = 0.0
    """A rollout whose garment sits on average more than this (m) above its skinned pose over its last third
    is not kept (``training.rollouts``): A would learn a garment creeping up the body as its place. 0: no check."""
    max_gap: float = 0.0
    """The same for a garment more than this (m, RMS over vertices) from its skinned pose (slid off); 0: no check."""
    max_detached_pct: float = 0.0
    """A rollout with more than this share (%) of its vertex-frames above the hips come off the body (over 10 cm
    farther from the skin than at its start: ``training.rollouts.detached_above_hips``) is not kept, in a bank or
    in the cache; 0: no check."""
    bank: str = ""
    """Folder of saved teacher rollouts (``hyperbones rollouts``): refreshes load the ones not yet cached and
    simulate only when none is left. Empty: every rollout is simulated as training goes."""

    def __post_init__(self) -> None:
        if self.frames_per_step < 1 or self.frames_per_rollout < 1 or self.frames_per_step % self.frames_per_rollout:
            raise ParameterError(f"joint.frames_per_rollout ({self.frames_per_rollout}) must divide "
                                 f"joint.frames_per_step ({self.frames_per_step}), both at least 1")


@dataclass(frozen=True)
class HyperBonesTrainingConfig(TeacherTrainingConfig):
    """The joint config: the teacher's sections plus Module A and phase 2's settings."""

    runtime: ModuleAConfig = ModuleAConfig()
    joint: JointConfig = JointConfig()


def load_config(path: str | Path) -> TeacherTrainingConfig:
    """A teacher config, or a HyperBones (joint) one when the file has a ``[joint]`` table."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "config file not found")
    try:
        values = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise InputFileError(path, f"not valid TOML ({error})") from None
    except RecursionError:
        raise InputFileError(path, "not valid TOML (nested too deeply)") from None
    except OSError as error:
        raise InputFileError(path, f"cannot be read ({error.strerror or error})") from None
    kind = HyperBonesTrainingConfig if "joint" in values else TeacherTrainingConfig
    return kind.from_dict(values, str(path))


Config = TypeVar("Config", bound=TeacherTrainingConfig)


def apply_overrides(config: Config, overrides: Iterable[str] | None, source: str = "--set") -> Config:
    """``config`` with each ``"section.key=value"`` of ``overrides`` applied (``--set``), checked as a file's.

    The value is read as a TOML value (``100``, ``1e-4``, ``true``, ``["01_01", "02_01"]``) or else, and
    always for a string field, as the bare text (``train.init_from=runs/teacher/checkpoint.pt``). The
    overrides of a section are applied together, so ``data.train_clips`` and ``data.validation_clips``
    can change in one call. ``None`` (no ``--set`` given) changes nothing. Problems are
    ``ParameterError``s naming ``source`` and the override.
    """
    sections = get_type_hints(type(config))
    changes: dict[str, dict[str, Any]] = {}
    given: dict[str, list[str]] = {}
    for text in overrides or ():
        option = f"{source} {text}"
        name, equals, raw = text.partition("=")
        section, dot, key = name.strip().partition(".")
        if not equals or not dot:
            raise ParameterError(f"{option}: expected section.key=value")
        if section not in sections:
            raise ParameterError(f"{option}: unknown section {section!r}; known: {', '.join(sections)}")
        keys = get_type_hints(sections[section])
        if key not in keys:
            raise ParameterError(f"{option}: unknown key {key!r} in [{section}]; known: {', '.join(keys)}")
        if key in changes.get(section, {}):
            raise ParameterError(f"{option}: {section}.{key} given twice")
        try:
            changes.setdefault(section, {})[key] = _coerce(keys[key], _parse_value(raw.strip(), keys[key]),
                                                           f"{section}.{key}")
        except _WrongType as error:
            raise ParameterError(f"{option}: {error}") from None
        given.setdefault(section, []).append(option)
    built = {}
    for section, values in changes.items():
        try:
            built[section] = replace(getattr(config, section), **values)
        except ParameterError as error:
            raise ParameterError(f"{' '.join(given[section])}: {error}") from None
    return replace(config, **built)


def _parse_value(raw: str, kind) -> Any:
    try:
        parsed = tomllib.loads(f"value = {raw}")
    except tomllib.TOMLDecodeError:
        return raw
    if set(parsed) != {"value"} or (kind is str and not isinstance(parsed["value"], str)):
        return raw
    return parsed["value"]


class _WrongType(ValueError):
    """A value that does not fit its field; the caller says which file or option it came from."""


_SIGNED = frozenset({"train.seed"})
"""The only numbers of a training config that may be negative; sizes, counts, rates, weights and
lengths may not."""


def _build(kind, values: Any, section: str, source: str):
    if not isinstance(values, dict):
        raise InputFileError(source, f"[{section}] must be a table")
    hints = get_type_hints(kind)
    unknown = set(values) - set(hints)
    if unknown:
        raise InputFileError(source, f"[{section}]: unknown key(s) {sorted(unknown)}; known: {sorted(hints)}")
    try:
        return kind(**{key: _coerce(hints[key], value, f"{section}.{key}") for key, value in values.items()})
    except (_WrongType, ParameterError) as error:
        raise InputFileError(source, str(error)) from None


def _coerce(kind, value: Any, where: str):
    origin = get_origin(kind)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise _WrongType(f"{where} must be a list, got {value!r}")
        items = get_args(kind)
        if Ellipsis not in items and len(value) != len(items):  # e.g. tuple[float, float]: exactly two
            raise _WrongType(f"{where} must be a list of {len(items)}, got {value!r}")
        return tuple(_coerce(items[0], item, where) for item in value)
    if origin is dict:
        if not isinstance(value, dict):
            raise _WrongType(f"{where} must be a table, got {value!r}")
        return {str(k): _coerce(get_args(kind)[1], v, where) for k, v in value.items()}
    if kind is bool and isinstance(value, bool):
        return value
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if (kind is float and number) or (kind is int and number and isinstance(value, int)):
        if not math.isfinite(value):  # TOML has nan and inf
            raise _WrongType(f"{where} must be a finite number, got {value!r}")
        if value < 0 and where not in _SIGNED:
            raise _WrongType(f"{where} must be >= 0, got {value!r}")
        return float(value) if kind is float else value
    if kind is str and isinstance(value, str):
        return value
    raise _WrongType(f"{where} must be {kind.__name__}, got {value!r}")
