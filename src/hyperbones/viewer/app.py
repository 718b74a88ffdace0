"""The browser viewer: a viser server showing a body and its garment in motion, with controls.

Every control change asks for a new scene (``Choice``); one worker thread makes the latest
asked for (body, drape, Module B's encoding, every frame: ``jobs.simulate.run_simulation``)
while the last one keeps playing, and abandons a scene that a newer change has replaced.
Playback only swaps precomputed vertices, so it runs at the motion's rate on any CPU.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np

from hyperbones.body.shape import PHENOTYPE_KEYS, BodyShape
from hyperbones.errors import HyperbonesError
from hyperbones.jobs.simulate import GARMENT_COLOR, SimulationResult, run_simulation
from hyperbones.viewer.choice import FABRIC_FIELDS, FABRIC_RANGE, VIEW_METHODS, Choice

BODY_RGB = (219, 184, 158)
GROUND_CELL = 0.25  # m
GARMENT_RGB = tuple(int(round(255 * channel)) for channel in GARMENT_COLOR)


class Superseded(Exception):
    """A newer choice replaced the scene being made."""


class Viewer:
    """A viser server on ``host``:``port`` showing ``choice`` and controls to change it.

    garments, motions: the names the dropdowns offer (templates and garment files; built-ins
    and .bvh files); the choice's own are added when missing. checkpoint: the learnt methods'
    (default: the shipped model). playing: start playing once the first scene is ready.
    """

    def __init__(self, choice: Choice, garments: list[str], motions: list[str], host: str = "127.0.0.1",
                 port: int = 8080, checkpoint: str | None = None, playing: bool = True):
        import viser
        # Scenes are made on a worker thread, and a new body's templates are meshed with
        # pymeshlab: loaded first by a thread other than the main one, pymeshlab's exit
        # handlers abort the process at exit (heap corruption, seen here). Load it here.
        import pymeshlab  # noqa: F401

        self.checkpoint = checkpoint
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (0.0, -2.6, 1.2)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.9)
        # The camera stays on the character: the meshes move back by the Hips' ground position,
        # and the floor by the same modulo its cells (the character walks over a still floor).
        self._world = self.server.scene.add_frame("/world", show_axes=False)
        self._ground = self.server.scene.add_grid("/ground", width=6.0, height=6.0, plane="xy", cell_size=GROUND_CELL)
        self.result: SimulationResult | None = None  # the scene shown
        # Its frames as the meshes take them: (T,Vb,3) and (T,V,3) float32; (T,2) the Hips over the floor.
        self.body_frames = self.garment_frames = self._centres = None
        self._initial = choice  # what the controls do not set (frames, vertices)
        self.shown: Choice | None = None
        self.ready = threading.Event()  # set while nothing asked for is still being made
        self._wanted = choice
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._meshes: dict[str, object] = {}
        self._frame = 0  # the frame on screen; the frame slider shows it and a user's drag sets it
        self._build_gui(choice, _unique([choice.garment, *garments]), _unique([choice.motion, *motions]), playing)
        self._worker = threading.Thread(target=self._work, name="viewer-scenes", daemon=True)
        self._player = threading.Thread(target=self._play, name="viewer-playback", daemon=True)
        self._worker.start()
        self._player.start()
        self._wake.set()

    @property
    def port(self) -> int:
        return self.server.get_port()

    def _build_gui(self, choice: Choice, garments: list[str], motions: list[str], playing: bool) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        self.status = gui.add_markdown("Starting…")
        self.progress = gui.add_progress_bar(0.0, animated=True)
        with gui.add_folder("Scene"):
            self.garment = gui.add_dropdown("Garment", garments, initial_value=choice.garment)
            self.motion = gui.add_dropdown("Motion", motions, initial_value=choice.motion)
            methods = {name: label for label, name in VIEW_METHODS.items()}
            self.method = gui.add_dropdown("Method", list(VIEW_METHODS), initial_value=methods[choice.method])
        with gui.add_folder("Body shape"):
            self.body = {key: gui.add_slider(key, 0.0, 1.0, 0.05, getattr(choice.body, key))
                         for key in PHENOTYPE_KEYS}
        with gui.add_folder("Fabric (× default cloth)"):
            low, high = FABRIC_RANGE
            self.fabric = {name: gui.add_slider(name, low, high, 0.05, value) for name, value in choice.fabric}
        with gui.add_folder("Playback"):
            self.playing = gui.add_checkbox("Play", playing)
            self.frame = gui.add_slider("Frame", 0, 1, 1, 0)
        self.metrics = gui.add_markdown("")
        for control in [self.garment, self.motion, self.method, *self.body.values(), *self.fabric.values()]:
            control.on_update(lambda _event: self.ask(self.choice_from_controls()))
        self.frame.on_update(self._scrubbed)

    def choice_from_controls(self) -> Choice:
        """The scene the controls describe now."""
        return replace(self._initial, garment=self.garment.value, motion=self.motion.value,
                       method=VIEW_METHODS[self.method.value],
                       body=BodyShape(**{key: float(slider.value) for key, slider in self.body.items()}),
                       fabric=tuple((name, float(self.fabric[name].value)) for name in FABRIC_FIELDS))

    def ask(self, choice: Choice) -> None:
        """Show ``choice`` once it is made (the current scene plays on until then)."""
        with self._lock:
            self._wanted = choice
            if choice != self.shown:
                self.ready.clear()
        self._wake.set()

    def wait_ready(self, timeout: float | None = None) -> bool:
        """Block until the scene last asked for is shown, or could not be made (the status line
        says why and the last scene stays); False on timeout."""
        return self.ready.wait(timeout)

    def close(self) -> None:
        """Stop playing and making scenes (waiting for a scene being made to give up), and the server."""
        self._closed.set()
        self._wake.set()
        self._player.join()
        self._worker.join()
        self.server.stop()

    # The worker: makes the scene last asked for.
    def _work(self) -> None:
        while True:
            self._wake.wait()
            if self._closed.is_set():
                return
            self._wake.clear()
            with self._lock:
                choice = self._wanted
            if choice == self.shown:
                self.ready.set()
                continue
            try:
                result = self._make(choice)
            except Superseded:
                continue
            except HyperbonesError as error:
                self.status.content = f"**Cannot show this scene:** {error}"
                self.progress.visible = False
                with self._lock:  # nothing newer to make: the last scene stays
                    if self._wanted == choice:
                        self._wanted = self.shown or choice
                        self.ready.set()
                continue
            self._install(choice, result)

    def _make(self, choice: Choice) -> SimulationResult:
        def report(stage: str, fraction: float) -> None:
            if self._wanted != choice or self._closed.is_set():
                raise Superseded
            self.status.content = f"{stage}…"
            self.progress.value = 100.0 * fraction

        self.progress.visible = True
        return run_simulation(choice.method, choice.garment, choice.motion, choice.body.label(),
                              frames=choice.frames, vertices=choice.vertices, material=choice.material(),
                              checkpoint=self.checkpoint, report=report)

    def _install(self, choice: Choice, result: SimulationResult) -> None:
        """Put a made scene on screen, at the frame shown so far (or its last)."""
        body = np.ascontiguousarray(result.body_vertices.numpy(), dtype=np.float32)
        garment = np.ascontiguousarray(result.garment_vertices.numpy(), dtype=np.float32)
        with self._lock:
            frame = self._frame = min(self._frame, body.shape[0] - 1)
            self._put("body", body[frame], result.body_faces.numpy(), BODY_RGB)
            self._put("garment", garment[frame], result.garment.faces.numpy(), GARMENT_RGB)
            self.result, self.shown, self.body_frames, self.garment_frames = result, choice, body, garment
            self._centres = result.joint_positions[:, 0, :2].numpy().astype(np.float64)  # (T,2) the Hips over the floor
            self._follow(frame)
            self.frame.max = max(body.shape[0] - 1, 1)
        self.frame.value = frame
        metrics = result.metrics
        self.metrics.content = (f"{body.shape[0]} frames at {metrics['fps']:g} fps, {metrics['garment_vertices']} "
                                f"garment vertices, {metrics['ms_median']:.1f} ms a frame (median); edge error "
                                f"{metrics['edge_error_pct']:.2f} %, vertices inside the body "
                                f"{metrics['collision_pct']:.3f} %")
        self.status.content = f"{choice.garment} on body {choice.body.label()}, {choice.motion}, {choice.method}"
        self.progress.visible = False
        with self._lock:
            if self._wanted == choice:
                self.ready.set()

    def _put(self, name: str, vertices: np.ndarray, faces: np.ndarray, color: tuple[int, int, int]) -> None:
        """Mesh ``name`` at ``vertices``: moved where its faces are the same, else made anew."""
        handle = self._meshes.get(name)
        if handle is not None and np.array_equal(handle.faces, faces):
            handle.vertices = vertices
            return
        if handle is not None:
            handle.remove()
        self._meshes[name] = self.server.scene.add_mesh_simple(
            f"/world/{name}", vertices, faces.astype(np.uint32), color=color, side="double")

    def _show(self, frame: int) -> None:
        """Frame ``frame`` of the scene on screen (clamped to its length), and on the frame slider."""
        with self._lock:
            if self.result is None:
                return
            frame = self._frame = min(max(frame, 0), self.body_frames.shape[0] - 1)
            self._meshes["body"].vertices = self.body_frames[frame]
            self._meshes["garment"].vertices = self.garment_frames[frame]
            self._follow(frame)
        self.frame.value = frame

    def _follow(self, frame: int) -> None:
        """Keep frame ``frame``'s Hips over the origin, the floor moving under them."""
        x, y = self._centres[frame]
        self._world.position = (-x, -y, 0.0)
        self._ground.position = (-(x % GROUND_CELL), -(y % GROUND_CELL), 0.0)

    def _scrubbed(self, event) -> None:
        """The frame slider moved: by a user (a client), show that frame; by the player or
        ``_show`` (no client), it already is."""
        if event.client is not None:
            self._show(int(self.frame.value))

    # The player: steps the frame at the motion's rate while "Play" is ticked.
    def _play(self) -> None:
        due = time.perf_counter()
        while not self._closed.is_set():
            result = self.result
            if result is None or not self.playing.value:
                time.sleep(0.05)
                due = time.perf_counter()
                continue
            self._show((self._frame + 1) % result.metrics["frames"])
            due += 1.0 / result.fps
            time.sleep(max(0.0, due - time.perf_counter()))
            due = max(due, time.perf_counter() - 0.5)  # after a stall, no burst of catching up


def _unique(names: list[str]) -> list[str]:
    return list(dict.fromkeys(names))
