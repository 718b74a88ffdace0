"""The typed training configuration, read from a TOML file and saved into every checkpoint.

A teacher config has three tables, ``[model]``, ``[data]`` and ``[train]``, with the fields
of ``TrunkConfig``, ``DataConfig`` and ``TrainConfig``. A HyperBones (joint, phase 2) config
adds ``[runtime]`` (``ModuleAConfig``) and ``[joint]`` (``JointConfig``); ``load_config``
tells them apart by the ``[joint]`` table. Anything left out takes the default below.
Unknown keys and wrongly typed values are errors that name the file.
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, get_args, get_origin, get_type_hints

from hyperbones.errors import InputFileError
from hyperbones.models.module_a import ModuleAConfig
from hyperbones.models.teacher import TrunkConfig

TEMPLATE_NAMES = ("tshirt", "tshirt-open", "pants", "long-skirt", "dress", "tight-dress")


@dataclass(frozen=True)
class DataConfig:
    """What the teacher trains on, and what is held out for evaluation.

    templates / resolutions: garments (made on the default body, carried to each sampled
        body along its surface) at these vertex counts.
    train_clips / test_clips: CMU clip names under ``mocap_dir``; test clips are never
        sampled. builtins: built-in motions also trained on.
    test_bodies: held-out shapes ("k=v,..."); sampled bodies stay at least
        ``test_body_margin`` (L2 over the six phenotype values) away from each.
    hold_seconds: stillness appended to every training clip, so settling is learnt.
    default_material_fraction: share of episodes with HOOD's default fabric; the others
        draw μ, λ, k_b, ρ over HOOD's ranges.
    start_noise: std (m) of the noise added to the LBS start; settle_dt: length (s) of the
        first step of an episode, taken with the body held still.
    airborne_fraction: share of episodes whose root gets free-fall hops added on top of
        the clip (``training.data.ballistic_hops``), launched at ``hop_speeds`` (m/s, a
        range): the clips hold a few tenths of a second of flight, too little to learn
        that cloth falls at g once the body drops away from it.
    drape: settle each carried garment on its body (``garment.drape``, cached on disk)
        before use, as ``simulate`` and ``eval`` do: rollouts start from the drape, and
        Module B's graph and the virtual bones' places are built on it (the bones' skinning
        weights come from the rest shape either way). Off: on the carried garment,
        which the first (settling) step of a rollout then drapes. The physics rest shape
        is the carried garment either way.
    """

    templates: tuple[str, ...] = TEMPLATE_NAMES
    resolutions: tuple[int, ...] = (1500, 2500)
    mocap_dir: str = "../shared/data/mocap/cmu"
    train_clips: tuple[str, ...] = ("01_01", "02_01", "02_03", "05_06", "111_10", "16_07", "16_27", "69_53", "74_06")
    test_clips: tuple[str, ...] = ("16_21", "16_35", "143_06")
    source_fps: dict[str, float] = field(default_factory=lambda: {"74_06": 60.0, "143_06": 60.0})
    builtins: tuple[str, ...] = ("walk", "run", "jump", "turn", "idle", "arm-swing", "sit")
    test_bodies: tuple[str, ...] = ("gender=0.3,age=0.6,muscle=0.7,weight=0.3,height=0.6,proportions=0.4",
                                    "gender=0.8,age=0.4,muscle=0.3,weight=0.8,height=0.3,proportions=0.6")
    test_body_margin: float = 0.25
    hold_seconds: float = 1.5
    default_material_fraction: float = 0.5
    start_noise: float = 0.001
    settle_dt: float = 1.0 / 3.0
    airborne_fraction: float = 0.0
    hop_speeds: tuple[float, float] = (0.8, 2.2)
    drape: bool = False


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation (HOOD's: Adam 5e-5, grad-norm clip 1, collision weight ramp, rollouts 1 → 5).

    init_from: a training checkpoint (path relative to the folder the command runs in) whose
        teacher weights and input statistics a new run starts from, with a fresh optimiser and
        step 0 (a joint checkpoint gives its Module C); its model section must match this
        config's. A joint (phase 2) run started from a joint checkpoint (a training one or
        an exported model) takes all of it, Modules A and B too (the moving average where
        the checkpoint keeps one): a fine-tuning run. Empty: random initialisation.
    learning_rate_halve_at: steps at which the learning rate halves (a staircase decay).
    ema_decay: the checkpoint also keeps an exponential moving average of the weights with
        this decay per step, and inference loads it (single steps of the one-step physics
        loss move the weights noisily; the average rolls out more steadily). 0: none.
    """

    steps: int = 100_000
    learning_rate: float = 5e-5
    learning_rate_halve_at: tuple[int, ...] = ()
    grad_clip: float = 1.0
    collision_weight_start: float = 5e3
    collision_weight_end: float = 5e5
    collision_ramp_steps: int = 50_000
    rollout_start: int = 1
    rollout_max: int = 5
    rollout_ramp_steps: int = 20_000
    checkpoint_every: int = 250
    log_every: int = 10
    seed: int = 0
    device: str = "auto"
    init_from: str = ""
    ema_decay: float = 0.999


@dataclass(frozen=True)
class TeacherTrainingConfig:
    model: TrunkConfig = TrunkConfig()
    data: DataConfig = DataConfig()
    train: TrainConfig = TrainConfig()

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "config") -> "TeacherTrainingConfig":
        sections = {f.name: f.type for f in fields(cls)}
        hints = get_type_hints(cls)
        unknown = set(values) - set(sections)
        if unknown:
            raise InputFileError(source, f"unknown section(s) {sorted(unknown)}; expected {sorted(sections)}")
        built = {name: _build(hints[name], values.get(name, {}), f"{source} [{name}]") for name in sections}
        return cls(**built)

    @classmethod
    def load(cls, path: str | Path) -> "TeacherTrainingConfig":
        config = load_config(path)
        if not isinstance(config, cls):
            raise InputFileError(path, f"expected a {cls.__name__.replace('TrainingConfig', '').lower()} config")
        return config


@dataclass(frozen=True)
class JointConfig:
    """Phase 2 (paper Sec. 3.5): C keeps training on L_phys while A learns C's rollouts.

    (Phase 2 starts from a phase-1 teacher run through ``train.init_from``: its weights start C
    and the shared trunk.)
    cache_size / rollout_frames: A's targets are C's states along ``cache_size`` whole
        rollouts of ``rollout_frames`` frames each, from the LBS start through the clip
        (no gradient); ``refresh_every`` steps the oldest is replaced by a new rollout of the
        current C, so the targets improve with C. ``end_fraction`` of the rollouts end where
        their clip ends (its hold), so A sees the cloth settle after the body stops.
    frames_per_step: cached frames A is trained on per optimiser step.
    position_scale: L_MSE and L_lap are taken in cm² (m² × 1e4) so that a centimetre of error
        weighs about as much as the energies (joules) of the physics terms.
    laplacian_weight / interpenetration_weight: λ_lap, λ_interp (paper 0.1; 0 = the ablation);
        interpenetration_epsilon: ε (m).  physics_on_runtime: stretching, bending and
        collision (L_phys's weights) on A's output too.
    trunk_from_runtime: A's loss also trains the shared trunk through Module B (the paper's
        joint training). Off by default, to keep the teacher's physics training as #4
        measured it: one gradient-norm clip covers the whole step, and A's L_3D (median
        148 cm² over the first 279 steps of a trial from the step-25000 teacher) is two
        orders of magnitude above C's physics terms (~1 J). B's heads learn from A's loss
        either way.
    max_rise / max_gap: a rollout whose garment, over the last third of its frames, sits on
        average more than ``max_rise`` (m) above its skinned pose, or more than ``max_gap``
        (m, RMS over vertices) away from it, is not kept as a target (``training.rollouts``):
        the teacher lets some garments creep up the body or slide off it, and A would learn
        that as the garment's place. 0 turns a check off.
    bank: a folder of saved rollouts (``hyperbones rollouts``); refreshes load from it
        (rollouts not already cached) and simulate only when it has none left. Empty: none.
    train_teacher: False freezes C and the shared trunk (the finished phase-1 teacher): a step
        is then A's terms alone, on ``frames_per_step`` cached frames, and each cached
        rollout's trunk latents are computed once. The CPU setting: C's own episode step
        costs most of a joint step, and its weights no longer need to move.
    """

    cache_size: int = 16
    rollout_frames: int = 150
    refresh_every: int = 200
    end_fraction: float = 0.3
    frames_per_step: int = 1
    position_scale: float = 1e4
    laplacian_weight: float = 0.1
    interpenetration_weight: float = 0.1
    interpenetration_epsilon: float = 0.003
    physics_on_runtime: bool = True
    trunk_from_runtime: bool = False
    train_teacher: bool = True
    max_rise: float = 0.0
    max_gap: float = 0.0
    bank: str = ""


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
        values = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise InputFileError(path, f"not valid TOML ({error})") from None
    kind = HyperBonesTrainingConfig if "joint" in values else TeacherTrainingConfig
    return kind.from_dict(values, str(path))


def _build(kind, values: Any, where: str):
    if not isinstance(values, dict):
        raise InputFileError(where.split(" [")[0], f"{where} must be a table")
    hints = get_type_hints(kind)
    unknown = set(values) - set(hints)
    if unknown:
        raise InputFileError(where.split(" [")[0], f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(hints)}")
    return kind(**{key: _coerce(hints[key], value, f"{where}.{key}") for key, value in values.items()})


def _coerce(kind, value: Any, where: str):
    origin = get_origin(kind)
    file = where.split(" [")[0]
    if origin is tuple:
        item = get_args(kind)[0]
        if not isinstance(value, (list, tuple)):
            raise InputFileError(file, f"{where} must be a list")
        return tuple(_coerce(item, v, where) for v in value)
    if origin is dict:
        if not isinstance(value, dict):
            raise InputFileError(file, f"{where} must be a table")
        key_kind, value_kind = get_args(kind)
        return {str(k): _coerce(value_kind, v, where) for k, v in value.items()}
    if kind is bool and isinstance(value, bool):
        return value
    if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if kind is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind is str and isinstance(value, str):
        return value
    raise InputFileError(file, f"{where} must be {kind.__name__}, got {value!r}")
