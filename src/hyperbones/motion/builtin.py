"""Built-in motions written by the project: no data files, deterministic, parametrised.

Each clip starts and ends standing (so an end hold is a real standstill) and keeps its
feet on the ground: feet are placed on the ground plane, legs are solved by IK, and the
pelvis is lowered wherever the legs could not reach.

Parameters shared by all clips: ``speed`` (a clip-specific unit, see BUILTINS),
``duration`` (seconds of motion before the hold) and ``hold`` (seconds of stillness at
the end).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch

from hyperbones.body.anny_body import Body
from hyperbones.errors import ParameterError
from hyperbones.geometry.rotations import rot_x, rot_y, rot_z
from hyperbones.motion.legs import SIDES, LegRig
from hyperbones.motion.motion import DEFAULT_FPS, Motion

GRAVITY = 9.81
# Foot pitch (radians) at toe-off (heel up, > 0) and at heel strike (toes up, < 0).
TOE_OFF_ROLL = 0.45
HEEL_STRIKE_ROLL = -0.25
# Leg length (hip to ankle, metres) of the default Anny body, at which the gait constants
# below were tuned; other bodies step proportionally (cadence x this / their leg length).
REFERENCE_LEG_LENGTH = 0.794


def _smoothstep(x: torch.Tensor) -> torch.Tensor:
    x = x.clamp(0, 1)
    return x * x * (3 - 2 * x)


def _envelope(t: torch.Tensor, duration: float, ramp: float) -> torch.Tensor:
    """(T,) 0 -> 1 over the first ``ramp`` seconds, 1 -> 0 over the last ``ramp`` seconds."""
    return _smoothstep(t / ramp) * _smoothstep((duration - t) / ramp)


def _smooth_lowering(required: torch.Tensor, fps: float, seconds: float = 0.12) -> torch.Tensor:
    """Smooth a (T,) non-negative lowering without ever going below it (max filter, then blur)."""
    radius = max(1, int(3 * seconds * fps))
    padded = torch.nn.functional.pad(required[None, None], (radius, radius), mode="replicate")
    dilated = torch.nn.functional.max_pool1d(padded, 2 * radius + 1, stride=1)[0, 0]
    x = torch.arange(-radius, radius + 1, dtype=torch.float32)
    kernel = torch.exp(-0.5 * (x / (seconds * fps)) ** 2)
    kernel /= kernel.sum()
    blurred = torch.nn.functional.conv1d(
        torch.nn.functional.pad(dilated[None, None], (radius, radius), mode="replicate"), kernel[None, None]
    )[0, 0]
    return torch.maximum(blurred, required)


@dataclass
class _Gait:
    """Cyclic stepping along a planar path; stance fraction ``duty`` (1 = both feet planted)."""

    cycle_hz: float
    duty: torch.Tensor  # (T,) per frame, in (0, 1]
    intensity: torch.Tensor  # (T,) 0 standing .. 1 full gait; scales the foot roll
    swing_height: float
    phase_offset: dict[str, float]


def _foot_tracks(rig: LegRig, t, path_xy, path_yaw, gait: _Gait, fps: float):
    """Ankle targets and foot rotations of stepping feet.

    A foot is planted while its phase is below the duty factor. Each stance plants the
    foot where the pelvis frame is at mid-stance; a swing moves it to the next plant on
    an arc. Stances roll from the heel onto the ball.
    """
    ankles, feet, toes = {}, {}, {}
    for side in SIDES:
        phase = torch.remainder(gait.cycle_hz * t + gait.phase_offset[side], 1.0)
        stance = (phase < gait.duty) | (gait.duty >= 0.999)
        flags = stance.tolist() + [None]
        runs, start = [], 0
        for i in range(1, len(flags)):
            if flags[i] != flags[i - 1]:
                runs.append((start, i, flags[i - 1]))
                start = i
        plant_xy, plant_yaw = {}, {}
        offset = rig.ankle[side][:2] - rig.root[:2]
        for k, (a, b, is_stance) in enumerate(runs):
            if is_stance:
                mid = (a + b - 1) // 2
                c, s = math.cos(float(path_yaw[mid])), math.sin(float(path_yaw[mid]))
                plant_xy[k] = path_xy[mid] + torch.tensor([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]])
                plant_yaw[k] = float(path_yaw[mid])
        ground_xy = torch.zeros(len(t), 2)
        yaw = torch.zeros(len(t))
        lift = torch.zeros(len(t))
        roll = torch.zeros(len(t))
        for k, (a, b, is_stance) in enumerate(runs):
            if is_stance:
                ground_xy[a:b] = plant_xy[k]
                yaw[a:b] = plant_yaw[k]
                n = b - a
                if n > 3 and float(gait.duty[a:b].mean()) < 0.999:
                    u = torch.linspace(0, 1, n)
                    # Heel strike (toes up) eases flat; late stance lifts the heel onto the ball.
                    roll[a:b] = HEEL_STRIKE_ROLL * _smoothstep(1 - u / 0.2) + TOE_OFF_ROLL * _smoothstep((u - 0.65) / 0.35)
                continue
            prev_k, next_k = k - 1, k + 1
            start_xy = plant_xy.get(prev_k, plant_xy.get(next_k))
            end_xy = plant_xy.get(next_k, start_xy)
            start_yaw = plant_yaw.get(prev_k, plant_yaw.get(next_k, 0.0))
            end_yaw = plant_yaw.get(next_k, start_yaw)
            if start_xy is None:  # never planted: stand in place
                start_xy = end_xy = path_xy[a] + offset
            u = (torch.arange(a, b, dtype=torch.float32) - a + 1) / (b - a + 1)
            w = _smoothstep(u)
            ground_xy[a:b] = start_xy + w[:, None] * (end_xy - start_xy)
            yaw[a:b] = start_yaw + w * (end_yaw - start_yaw)
            # Early and late swings are short and quick: they lift as little as the gait is intense.
            amplitude = gait.swing_height * float(gait.intensity[(a + b) // 2])
            lift[a:b] = amplitude * torch.sin(math.pi * u)
            # From the toe-off roll to the heel-strike roll, toe down early and toe up late.
            roll[a:b] = TOE_OFF_ROLL * (1 - w) + HEEL_STRIKE_ROLL * w + 0.3 * torch.sin(2 * math.pi * u) * torch.sin(math.pi * u)
        yaw_rot = rot_z(yaw)
        roll = roll * gait.intensity  # short first and last steps barely roll
        ankle, foot = rig.planted_foot(side, ground_xy, yaw_rot, roll)
        # In swing, lift the whole foot; the roll pivot is then irrelevant.
        ankle = ankle + lift[:, None] * torch.tensor([0.0, 0.0, 1.0])
        # Toes stay level while the heel is up (the toe joint bends), and follow the foot
        # when the toes are up; one rule for stance and swing keeps them continuous.
        ankles[side], feet[side] = ankle, foot
        toes[side] = yaw_rot @ rot_x(roll.clamp(max=0))
    return ankles, feet, toes


def _assemble(rig: LegRig, t, fps, root_xy, root_z, pelvis, ankles, feet, torso, head, arms, name,
              toes=None) -> Motion:
    allowed = rig.max_root_height(root_xy, pelvis, ankles)
    lowering = _smooth_lowering((root_z - allowed).clamp(min=0), fps)
    root = torch.cat([root_xy, (root_z - lowering)[:, None]], dim=-1)
    rot = rig.solve(root, pelvis, ankles, feet, torso, head, arms, toes)
    return Motion(rot, root, fps, name)


def _locomotion(body: Body, name: str, speed: float, duration: float, fps: float, *, cadence: float,
                duty: float, swing_height: float, turn_rate: float = 0.0, lean: float = 0.05,
                arm_swing: float = 0.35, elbow: float = 0.25, bob: float = 0.015) -> Motion:
    rig = LegRig(body)
    k = body_scale(body)
    t = torch.arange(int(round(duration * fps)) + 1, dtype=torch.float32) / fps
    cycle = 1.0 / cadence
    env = _envelope(t, duration, ramp=min(cycle, duration / 3))
    # Heading and forward travel: the velocity follows the envelope, so start and end are still.
    yaw = torch.cumsum(turn_rate * env, 0) / fps
    yaw = yaw - yaw[0]
    forward = torch.stack([-torch.sin(yaw), -torch.cos(yaw)], dim=-1)  # facing -Y at yaw 0
    velocity = speed * env[:, None] * forward
    root_xy = rig.root[:2] + torch.cumsum(velocity, 0) / fps - velocity[0] / fps
    gait = _Gait(cadence, 1.0 - (1.0 - duty) * env, env, swing_height * k, {"left": 0.0, "right": 0.5})
    ankles, feet, toes = _foot_tracks(rig, t, root_xy, yaw, gait, fps)
    phase = 2 * math.pi * cadence * t
    pelvis = rot_z(yaw + 0.08 * env * torch.sin(phase)) @ rot_y(0.04 * env * torch.sin(phase))
    root_z = rig.root[2] - k * (0.01 + bob * env * (1 + torch.cos(2 * phase)) / 2)
    torso = rot_x(-lean * env) @ rot_z(-0.12 * env * torch.sin(phase))
    head = rot_z(0.06 * env * torch.sin(phase))
    arms = {
        side: rig.arm(side, arm_swing * env * torch.sin(phase + (0 if side == "right" else math.pi)),
                      elbow * env + 0.15 * env * (1 + torch.sin(phase + (0 if side == "right" else math.pi))))
        for side in SIDES
    }
    return _assemble(rig, t, fps, root_xy, root_z, pelvis, ankles, feet, torso, head, arms, name, toes)


def body_scale(body: Body) -> float:
    """Leg length relative to the default body: lengths of the clips scale with it, timing does not."""
    return body.leg_length / REFERENCE_LEG_LENGTH


def walk(body: Body, speed: float = 1.2, duration: float = 6.0, fps: float = DEFAULT_FPS) -> Motion:
    """Walk forward (-Y) at ``speed`` m/s."""
    # Gait cycles per second (two steps each), set by the speed in leg lengths per second,
    # so a small body at a given speed steps like a large one at a proportional speed.
    cadence = 0.75 + 0.2 * speed / body_scale(body)
    return _locomotion(body, "walk", speed, duration, fps, cadence=cadence, duty=0.62, swing_height=0.12)


def run(body: Body, speed: float = 2.5, duration: float = 6.0, fps: float = DEFAULT_FPS) -> Motion:
    """Jog forward at ``speed`` m/s (short flight phases)."""
    cadence = 1.2 + 0.1 * speed / body_scale(body)
    return _locomotion(body, "run", speed, duration, fps, cadence=cadence, duty=0.4, swing_height=0.2,
                       lean=0.15, arm_swing=0.6, elbow=1.2, bob=0.04)


def turn(body: Body, speed: float = 0.25, duration: float = 6.0, fps: float = DEFAULT_FPS) -> Motion:
    """Step in place while spinning at ``speed`` turns per second."""
    return _locomotion(body, "turn", 0.0, duration, fps, cadence=0.9, duty=0.65, swing_height=0.08,
                       turn_rate=2 * math.pi * speed, lean=0.02, arm_swing=0.2)


def _standing(body: Body, t: torch.Tensor):
    rig = LegRig(body)
    n = len(t)
    yaw = torch.eye(3).expand(n, 3, 3)
    ankles, feet = {}, {}
    for side in SIDES:
        ankles[side], feet[side] = rig.planted_foot(side, rig.ankle[side][:2].expand(n, 2), yaw, torch.zeros(n))
    return rig, ankles, feet


def idle(body: Body, speed: float = 1.0, duration: float = 8.0, fps: float = DEFAULT_FPS) -> Motion:
    """Stand and sway: weight shifts side to side, breathing; ``speed`` scales the tempo."""
    t = torch.arange(int(round(duration * fps)) + 1, dtype=torch.float32) / fps
    rig, ankles, feet = _standing(body, t)
    env = _envelope(t, duration, ramp=min(1.0, duration / 3))
    w = 2 * math.pi * 0.25 * speed * t
    k = body_scale(body)
    root_xy = rig.root[:2] + k * torch.stack([0.03 * env * torch.sin(w), 0.01 * env * torch.sin(2 * w)], -1)
    root_z = rig.root[2] - k * (0.015 * env + 0.01 * env * torch.sin(w) ** 2)
    pelvis = rot_y(0.05 * env * torch.sin(w)) @ rot_z(0.04 * env * torch.sin(0.5 * w))
    torso = rot_y(-0.07 * env * torch.sin(w)) @ rot_x(0.02 * env * torch.sin(4 * w))
    head = rot_z(0.1 * env * torch.sin(0.7 * w)) @ rot_y(0.02 * env * torch.sin(w))
    arms = {side: rig.arm(side, 0.08 * env * torch.sin(w + (0 if side == "left" else 1.0)), 0.15 + 0.1 * env)
            for side in SIDES}
    return _assemble(rig, t, fps, root_xy, root_z, pelvis, ankles, feet, torso, head, arms, "idle")


def arm_swing(body: Body, speed: float = 1.0, duration: float = 6.0, fps: float = DEFAULT_FPS) -> Motion:
    """Stand and swing both arms forward and back in opposition; ``speed`` in swings per second."""
    t = torch.arange(int(round(duration * fps)) + 1, dtype=torch.float32) / fps
    rig, ankles, feet = _standing(body, t)
    env = _envelope(t, duration, ramp=min(1.0, duration / 3))
    w = 2 * math.pi * 0.5 * speed * t
    root_xy = rig.root[:2].expand(len(t), 2)
    root_z = rig.root[2] - body_scale(body) * (0.02 * env + 0.01 * env * torch.sin(2 * w) ** 2)
    pelvis = rot_z(0.06 * env * torch.sin(w))
    torso = rot_z(0.15 * env * torch.sin(w))
    head = rot_z(-0.15 * env * torch.sin(w))
    arms = {side: rig.arm(side, 0.9 * env * torch.sin(w + (0 if side == "left" else math.pi)), 0.3 * env)
            for side in SIDES}
    return _assemble(rig, t, fps, root_xy, root_z, pelvis, ankles, feet, torso, head, arms, "arm-swing")


def _keyframes(t: torch.Tensor, times: list[float], values: list[float]) -> torch.Tensor:
    """(T,) piecewise smoothstep interpolation through (time, value) keys (zero slope at keys)."""
    out = torch.full_like(t, values[0])
    for (t0, v0), (t1, v1) in zip(zip(times, values), zip(times[1:], values[1:])):
        inside = (t >= t0) & (t <= t1)
        out = torch.where(inside, v0 + (v1 - v0) * _smoothstep((t - t0) / max(t1 - t0, 1e-6)), out)
    return torch.where(t > times[-1], torch.full_like(t, values[-1]), out)


def sit(body: Body, speed: float = 1.0, duration: float = 5.0, fps: float = DEFAULT_FPS) -> Motion:
    """Sit down onto an (invisible) chair and stay seated; ``speed`` scales the tempo."""
    t = torch.arange(int(round(duration * fps)) + 1, dtype=torch.float32) / fps
    rig, ankles, feet = _standing(body, t)
    k = [0.0, 0.4 / speed, 1.3 / speed, 2.0 / speed]
    leg = rig.leg_length
    back = _keyframes(t, k, [0.0, 0.025 * leg, 0.33 * leg, 0.36 * leg])
    down = _keyframes(t, k, [0.0, 0.04 * leg, 0.40 * leg, 0.42 * leg])
    lean = _keyframes(t, k + [2.6 / speed], [0.0, 0.2, 0.55, 0.2, 0.1])
    arms_forward = _keyframes(t, k, [0.0, 0.3, 0.6, 0.5])
    root_xy = rig.root[:2] + torch.stack([torch.zeros_like(t), back], -1)
    root_z = rig.root[2] - 0.0125 * leg - down
    pelvis = rot_x(-0.6 * lean)
    torso = rot_x(-0.5 * lean)
    head = rot_x(0.4 * lean)
    arms = {side: rig.arm(side, arms_forward, 0.3 + 0.5 * arms_forward) for side in SIDES}
    return _assemble(rig, t, fps, root_xy, root_z, pelvis, ankles, feet, torso, head, arms, "sit")


def jump(body: Body, speed: float = 1.0, duration: float = 5.0, fps: float = DEFAULT_FPS, height: float = 0.25) -> Motion:
    """Vertical jumps in place; ``speed`` scales the tempo of crouch and landing.

    ``height`` is in metres for the default body; other bodies jump in proportion to their
    leg length with the same timing (the vertical path is scaled as a whole).
    """
    t = torch.arange(int(round(duration * fps)) + 1, dtype=torch.float32) / fps
    rig, ankles, feet = _standing(body, t)
    k = body_scale(body)
    takeoff_speed = math.sqrt(2 * GRAVITY * height)
    flight = 2 * takeoff_speed / GRAVITY
    crouch, push, land = 0.45 / speed, 0.18 / speed, 0.6 / speed
    period = crouch + push + flight + land + 0.3 / speed
    base = rig.root[2] - 0.01 * k
    dz = torch.zeros_like(t)
    arm = torch.zeros_like(t)
    num_jumps = max(1, int((duration - 0.5) // period))
    for j in range(num_jumps):
        t0 = 0.3 + j * period
        s = t - t0
        crouching = (s >= 0) & (s < crouch)
        dz = torch.where(crouching, -0.14 * _smoothstep(s / crouch), dz)
        pushing = (s >= crouch) & (s < crouch + push)
        u = (s - crouch) / push
        # Cubic from the crouch (rest) to the take-off height 0.04 with the take-off speed.
        h0, h1, v1 = -0.14, 0.04, takeoff_speed * push
        cubic = h0 + (3 * (h1 - h0) - v1) * u**2 + (v1 - 2 * (h1 - h0)) * u**3
        dz = torch.where(pushing, cubic, dz)
        flying = (s >= crouch + push) & (s < crouch + push + flight)
        f = s - crouch - push
        dz = torch.where(flying, 0.04 + takeoff_speed * f - 0.5 * GRAVITY * f**2, dz)
        landing = (s >= crouch + push + flight) & (s < period)
        g = ((s - crouch - push - flight) / land).clamp(max=1.0)
        # Landing: arrive at +0.04 moving down at take-off speed, absorb to -0.1, rise back to 0.
        absorb = 0.04 - takeoff_speed * land * g * (1 - g) ** 2 - 0.1 * _smoothstep(g / 0.45) * (1 - _smoothstep((g - 0.45) / 0.55)) - 0.04 * _smoothstep(g)
        dz = torch.where(landing, absorb, dz)
        # Arms: back during the crouch, up through take-off, down again on landing.
        inside = (s >= 0) & (s < period)
        arm_keys = [0.0, crouch, crouch + push + 0.12, crouch + push + flight, period - 0.1 / speed]
        arm = torch.where(inside, _keyframes(s, arm_keys, [0.0, -0.5, 1.2, 0.6, 0.0]), arm)
    dz = dz * k
    root_z = base + dz
    for side in SIDES:
        # The feet leave the ground only once the hips rise above their standing height.
        lift = (dz - 0.005 * k).clamp(min=0)
        ankles[side] = ankles[side] + lift[:, None] * torch.tensor([0.0, 0.0, 1.0])
        feet[side] = feet[side] @ rot_x(2.0 * lift / k)
    root_xy = rig.root[:2].expand(len(t), 2)
    crouch_amount = (-dz).clamp(min=0) / (0.14 * k)
    pelvis = rot_x(-0.35 * crouch_amount)
    torso = rot_x(-0.25 * crouch_amount)
    head = rot_x(0.3 * crouch_amount)
    arms = {side: rig.arm(side, arm, 0.3 + 0.2 * crouch_amount) for side in SIDES}
    return _assemble(rig, t, fps, root_xy, root_z, pelvis, ankles, feet, torso, head, arms, "jump")


@dataclass(frozen=True)
class Builtin:
    """A built-in clip: its generator, the unit of ``speed`` and default parameters."""

    make: Callable[..., Motion]
    speed_unit: str
    default_speed: float
    default_duration: float
    description: str


BUILTINS: dict[str, Builtin] = {
    "walk": Builtin(walk, "m/s", 1.2, 6.0, "walk forward"),
    "run": Builtin(run, "m/s", 2.5, 6.0, "jog forward"),
    "jump": Builtin(jump, "tempo", 1.0, 5.0, "vertical jumps in place"),
    "turn": Builtin(turn, "turns/s", 0.25, 6.0, "step in place while spinning"),
    "idle": Builtin(idle, "tempo", 1.0, 8.0, "stand, sway, breathe"),
    "arm-swing": Builtin(arm_swing, "swings/s", 1.0, 6.0, "swing both arms standing"),
    "sit": Builtin(sit, "tempo", 1.0, 5.0, "sit down on a chair and stay seated"),
}


def builtin_motion(name: str, body: Body, speed: float | None = None, duration: float | None = None,
                   hold: float = 0.0, fps: float = DEFAULT_FPS) -> Motion:
    """A built-in clip fitted to ``body``, with ``hold`` seconds of stillness at the end."""
    if name not in BUILTINS:
        raise ParameterError(f"unknown built-in motion {name!r}; available: {', '.join(BUILTINS)}")
    spec = BUILTINS[name]
    if speed is None:
        # Default walking and running speeds are for the default body; others move in proportion.
        speed = spec.default_speed * (body_scale(body) if spec.speed_unit == "m/s" else 1.0)
    duration = spec.default_duration if duration is None else duration
    if not (speed > 0 or (name == "walk" and speed == 0)):
        raise ParameterError(f"--speed must be positive for {name}, got {speed}")
    if not 0.5 <= duration <= 600:
        raise ParameterError(f"--duration must be between 0.5 and 600 s, got {duration}")
    if hold < 0:
        raise ParameterError(f"--hold must be >= 0, got {hold}")
    motion = spec.make(body, speed=speed, duration=duration, fps=fps)
    return motion.with_hold(int(round(hold * fps)))
