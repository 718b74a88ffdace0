"""Output faults: a read-only folder or a full disk is one line on stderr (exit 2), and nothing
half-written stays behind: no partial file, no temporary file, no part of a multi-file set, and an
earlier run's outputs are as they were.

A read-only folder is chmod 0o555; where that does not stop this process (root), every way the
writers make a file or folder in it raises EACCES, as the kernel would. A full disk is injected
as OSError(ENOSPC) at one point of an output (a write stops half way, a rename fails, the ffmpeg
pipe breaks, torch.save fails) with the disk reported full by os.statvfs.
"""

import builtins
import dataclasses
import errno
import hashlib
import io
import os
from pathlib import Path

import pytest
import torch
from test_training_trainer import TINY_TOML

from hyperbones.cli import main
from hyperbones.errors import OutputError
from hyperbones.io_utils import atomic_path

NO_SPACE = os.strerror(errno.ENOSPC)
DENIED = os.strerror(errno.EACCES)
TEACHER = Path(__file__).resolve().parents[1] / "src" / "hyperbones" / "checkpoints" / "teacher.pt"


# ---------------------------------------------------------------------------------------------
# Helpers: what a folder holds, one-line errors, the two kinds of fault


def snapshot(folder: Path) -> dict[str, str]:
    """Everything under ``folder``, hidden entries too: relative path -> hash of the bytes
    ("folder" for a folder); {} when ``folder`` does not exist."""
    found = {}
    for root, folders, files in os.walk(folder):
        for name in folders:
            found[os.path.relpath(os.path.join(root, name), folder)] = "folder"
        for name in files:
            path = os.path.join(root, name)
            found[os.path.relpath(path, folder)] = hashlib.sha1(Path(path).read_bytes()).hexdigest()
    return found


def run(capfd, *argv) -> tuple[int, str, str]:
    """The command line on ``argv``; (exit code, stdout, stderr), captured at the file
    descriptors so that a writer process's own lines (ffmpeg) would show."""
    code = main([str(arg) for arg in argv])
    out, err = capfd.readouterr()
    return code, out, err


def assert_one_line(code: int, err: str, *phrases: str) -> None:
    assert code == 2, err
    assert err.startswith("hyperbones: error: ") and err.count("\n") == 1, err
    for phrase in phrases:
        assert phrase in err, err


def _writes(mode: str) -> bool:
    return any(flag in mode for flag in "wax+")


@pytest.fixture
def read_only(tmp_path, monkeypatch):
    """A folder that refuses to be written into."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        (folder / "probe").touch()
    except PermissionError:
        pass
    else:  # root: the mode does not stop it
        (folder / "probe").unlink()
        _refuse_writes_under(folder, monkeypatch)
    yield folder
    folder.chmod(0o755)


def _refuse_writes_under(folder: Path, monkeypatch) -> None:
    """Make, open for writing and rename into anything under ``folder`` raise EACCES. Writers
    in C++ (torch, USD, ffmpeg) still write their temporary file; the rename into place fails."""
    def inside(path) -> bool:
        return isinstance(path, (str, os.PathLike)) and folder in Path(os.path.abspath(path)).parents

    def denied(path) -> PermissionError:
        return PermissionError(errno.EACCES, DENIED, os.fspath(path))

    real_open, real_mkdir, real_replace = io.open, os.mkdir, os.replace

    def guarded_open(file, mode="r", *args, **kwargs):
        if _writes(mode) and inside(file):
            raise denied(file)
        return real_open(file, mode, *args, **kwargs)

    def guarded_mkdir(path, *args, **kwargs):
        if inside(path):
            raise denied(path)
        return real_mkdir(path, *args, **kwargs)

    def guarded_replace(source, target, *args, **kwargs):
        if inside(target):
            raise denied(target)
        return real_replace(source, target, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded_open)
    monkeypatch.setattr(io, "open", guarded_open)
    monkeypatch.setattr(os, "mkdir", guarded_mkdir)
    monkeypatch.setattr(os, "replace", guarded_replace)


def disk_full(monkeypatch) -> None:
    """os.statvfs says what it says of a full disk: no block left."""
    real = os.statvfs

    def statvfs(path):
        s = real(path)
        return os.statvfs_result((s.f_bsize, s.f_frsize, s.f_blocks, 0, 0, s.f_files, s.f_ffree, s.f_favail,
                                  s.f_flag, s.f_namemax))

    monkeypatch.setattr(os, "statvfs", statvfs)


class _FillingFile:
    """A file that takes half of the first write, then raises ENOSPC (the disk is full)."""

    def __init__(self, handle):
        self._handle = handle

    def write(self, data):
        self._handle.write(data[: len(data) // 2])
        self._handle.flush()
        raise OSError(errno.ENOSPC, NO_SPACE)

    def writelines(self, lines):
        self.write("".join(lines))

    def __getattr__(self, name):
        return getattr(self._handle, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._handle.close()


def fill_on_write(monkeypatch, name_matches) -> None:
    """The disk fills up while a file whose name ``name_matches(name)`` is written."""
    real_open = io.open

    def open_(file, mode="r", *args, **kwargs):
        handle = real_open(file, mode, *args, **kwargs)
        if _writes(mode) and isinstance(file, (str, os.PathLike)) and name_matches(Path(file).name):
            return _FillingFile(handle)
        return handle

    monkeypatch.setattr(builtins, "open", open_)
    monkeypatch.setattr(io, "open", open_)
    disk_full(monkeypatch)


def fail_rename(monkeypatch, matches) -> None:
    """os.replace(source, target) raises ENOSPC when ``matches(source, target)``."""
    real_replace = os.replace

    def replace(source, target, *args, **kwargs):
        if matches(Path(source), Path(target)):
            raise OSError(errno.ENOSPC, NO_SPACE, os.fspath(target))
        return real_replace(source, target, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    disk_full(monkeypatch)


def torch_save_fails(monkeypatch, name_part: str = "") -> None:
    """torch.save to a path whose name holds ``name_part`` writes part of the file, then
    raises what torch raises when the disk fills up (a RuntimeError of its zip writer)."""
    real_save = torch.save

    def save(obj, f, *args, **kwargs):
        if isinstance(f, (str, os.PathLike)) and name_part in Path(f).name:
            Path(f).write_bytes(b"PK\x03\x04partial")
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 576 vs 534")
        return real_save(obj, f, *args, **kwargs)

    monkeypatch.setattr(torch, "save", save)
    disk_full(monkeypatch)


def faulty_folder(fault: str, request, name: str, fill) -> tuple[Path, str]:
    """(a folder that refuses writes, "Permission denied") for ``fault`` "read-only"; for "full
    disk", (an empty folder, "No space left on device") with the disk filling up as ``fill``
    (called with monkeypatch) makes it."""
    if fault == "read-only":
        return request.getfixturevalue("read_only"), DENIED
    folder = request.getfixturevalue("tmp_path") / name
    folder.mkdir()
    fill(request.getfixturevalue("monkeypatch"))
    return folder, NO_SPACE


# ---------------------------------------------------------------------------------------------
# atomic_path, the single-file writer under every output


def test_atomic_path_turns_a_full_disk_into_one_output_error(tmp_path):
    target = tmp_path / "a.json"
    target.write_text("earlier")
    with pytest.raises(OutputError) as caught:
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, NO_SPACE)
    assert str(caught.value) == f"{target}: cannot write: {NO_SPACE}"
    assert snapshot(tmp_path) == {"a.json": hashlib.sha1(b"earlier").hexdigest()}


def test_atomic_path_removes_the_folders_it_made_when_the_rename_fails(tmp_path, monkeypatch):
    fail_rename(monkeypatch, lambda source, target: target.name == "a.json")
    with pytest.raises(OutputError, match=NO_SPACE):
        with atomic_path(tmp_path / "new" / "deeper" / "a.json") as tmp:
            tmp.write_text("whole")
    assert snapshot(tmp_path) == {}


def test_atomic_path_names_torchs_write_failure_by_the_disk(tmp_path, monkeypatch):
    torch_save_fails(monkeypatch)
    with pytest.raises(OutputError) as caught:
        with atomic_path(tmp_path / "state.pt") as tmp:
            torch.save({"step": 1}, tmp)
    assert str(caught.value) == f"{tmp_path / 'state.pt'}: cannot write: {NO_SPACE}"
    assert snapshot(tmp_path) == {}


def test_atomic_path_lets_other_errors_through(tmp_path):
    """A bug in what is written is not an output fault: it keeps its type (and traceback)."""
    with pytest.raises(ValueError, match="not a fault of the disk"):
        with atomic_path(tmp_path / "a.json") as tmp:
            tmp.write_text("half")
            raise ValueError("not a fault of the disk")
    assert snapshot(tmp_path) == {}


# ---------------------------------------------------------------------------------------------
# simulate: six files (+ obj/), all or nothing


@pytest.fixture(scope="module")
def simulated():
    """(a 4-frame lbs run of a ~1000-vertex tshirt, the same cut to 3 frames: an earlier run)."""
    from hyperbones.jobs.simulate import run_simulation

    result = run_simulation("lbs", "tshirt", "walk", None, frames=4, vertices=1000)
    cut = {"garment_vertices": result.garment_vertices[:3], "body_vertices": result.body_vertices[:3],
           "joint_positions": result.joint_positions[:3], "metrics": {**result.metrics, "frames": 3}}
    return result, dataclasses.replace(result, **cut)


def simulate(capfd, monkeypatch, result, out: Path, *flags) -> tuple[int, str, str]:
    """``hyperbones simulate`` writing ``result`` (the simulation itself is not redone)."""
    monkeypatch.setattr("hyperbones.jobs.simulate.run_simulation", lambda *args, **kwargs: result)
    return run(capfd, "simulate", "--method", "lbs", "--garment", "tshirt", "--vertices", "1000", "--out", out,
               "--quiet", *flags)


def _staged(source: Path) -> bool:
    return source.parent.name.startswith(".staging-")


FAULTS = {  # where the disk fills up -> how it is injected
    "frames.npz": lambda mp: fill_on_write(mp, lambda name: name.endswith(".npz")),
    "garment.pc2": lambda mp: fill_on_write(mp, lambda name: name.endswith(".pc2")),
    "scene.usd": lambda mp: fail_rename(mp, lambda source, target: target.name == "scene.usd"),
    "obj": lambda mp: fill_on_write(mp, lambda name: name == "garment_0002.obj"),
    "metrics.json": lambda mp: fill_on_write(mp, lambda name: name.endswith(".json")),
    # The set is complete in the staging folder; the third rename into the output folder fails.
    "moving in": lambda mp: fail_rename(mp, lambda source, target: _staged(source) and not _staged(target)
                                        and target.name == "metrics.json"),
}


@pytest.mark.parametrize("fault", FAULTS)
def test_simulate_full_disk_keeps_the_earlier_run(fault, simulated, tmp_path, monkeypatch, capfd):
    result, earlier = simulated
    out = tmp_path / "run"
    assert simulate(capfd, monkeypatch, earlier, out, "--no-preview", "--obj")[0] == 0
    before = snapshot(out)
    assert {"frames.npz", "garment.pc2", "scene.usd", "metrics.json", "obj/garment_0002.obj"} <= set(before)
    FAULTS[fault](monkeypatch)
    code, _, err = simulate(capfd, monkeypatch, result, out, "--no-preview", "--obj")
    assert_one_line(code, err, NO_SPACE, str(out))
    assert ".staging" not in err  # the message names the output, not its staged copy
    assert snapshot(out) == before


def test_simulate_full_disk_leaves_no_folder_behind(simulated, tmp_path, monkeypatch, capfd):
    FAULTS["scene.usd"](monkeypatch)
    code, _, err = simulate(capfd, monkeypatch, simulated[0], tmp_path / "new" / "run", "--no-preview")
    assert_one_line(code, err, f"{tmp_path / 'new' / 'run' / 'scene.usd'}: cannot write: {NO_SPACE}")
    assert snapshot(tmp_path) == {}


class _BreakingWriter:
    """The preview's ffmpeg writer whose ffmpeg dies of a full disk: the pipe breaks at frame 2
    (``breaks``), or ffmpeg ends early and silently, leaving a cut video (imageio does not
    check how ffmpeg ended)."""

    def __init__(self, real, path, breaks: bool):
        self.real, self.path, self.breaks, self.frames = real, Path(path), breaks, 0

    def append_data(self, frame):
        self.frames += 1
        if self.breaks and self.frames == 2:
            raise OSError(errno.EPIPE, "Broken pipe\n\nFFMPEG COMMAND:\nffmpeg ...\n\nFFMPEG STDERR OUTPUT:\n")
        self.real.append_data(frame)

    def close(self):
        self.real.close()
        if not self.breaks:
            with open(self.path, "r+b") as f:
                f.truncate(self.path.stat().st_size // 2)


@pytest.mark.parametrize("fault", ["pipe breaks", "video cut short", "sheet"])
def test_simulate_preview_on_a_full_disk(fault, simulated, tmp_path, monkeypatch, capfd):
    """The one case with the preview: ffmpeg's failures too are one line, with nothing of
    ffmpeg's own on stderr, and the earlier run stays."""
    import imageio.v2 as imageio

    result, earlier = simulated
    out = tmp_path / "run"
    assert simulate(capfd, monkeypatch, earlier, out)[0] == 0
    before = snapshot(out)
    assert {"preview.mp4", "preview_sheet.png"} <= set(before)
    if fault == "sheet":
        fill_on_write(monkeypatch, lambda name: name.endswith(".png"))
    else:
        real_writer = imageio.get_writer
        monkeypatch.setattr(imageio, "get_writer", lambda path, **kwargs: _BreakingWriter(
            real_writer(path, **kwargs), path, breaks=fault == "pipe breaks"))
        disk_full(monkeypatch)
    code, _, err = simulate(capfd, monkeypatch, result, out)
    name = "preview_sheet.png" if fault == "sheet" else "preview.mp4"
    assert_one_line(code, err, f"{out / name}: cannot write: {NO_SPACE}")
    assert snapshot(out) == before


@pytest.mark.parametrize("where", ["the folder", "a folder inside it"])
def test_simulate_into_a_read_only_folder(where, simulated, read_only, monkeypatch, capfd):
    out = read_only if where == "the folder" else read_only / "run"
    code, _, err = simulate(capfd, monkeypatch, simulated[0], out, "--no-preview")
    assert_one_line(code, err, f"{out}: cannot write: {DENIED}")
    assert snapshot(read_only) == {}


# ---------------------------------------------------------------------------------------------
# The other verbs that write


def _eval_stub(monkeypatch, result) -> list:
    calls = []
    monkeypatch.setattr("hyperbones.jobs.evaluate.run_simulation",
                        lambda *args, **kwargs: calls.append(args) or result)
    return calls


EVAL = ("eval", "--methods", "lbs", "--garments", "tshirt", "--vertices", "1000", "--motions", "walk", "--quiet")


def test_eval_read_only_fails_before_the_first_run(simulated, read_only, monkeypatch, capfd):
    calls = _eval_stub(monkeypatch, simulated[0])
    code, _, err = run(capfd, *EVAL, "--out", read_only / "eval")
    assert_one_line(code, err, f"{read_only / 'eval'}: cannot write: {DENIED}")
    assert calls == [] and snapshot(read_only) == {}


def test_eval_full_disk_writes_neither_report(simulated, tmp_path, monkeypatch, capfd):
    _eval_stub(monkeypatch, simulated[0])
    fill_on_write(monkeypatch, lambda name: name.endswith(".md"))  # report.json is written first
    code, _, err = run(capfd, *EVAL, "--out", tmp_path / "eval")
    assert_one_line(code, err, f"{tmp_path / 'eval' / 'report.md'}: cannot write: {NO_SPACE}")
    assert snapshot(tmp_path) == {}


FAULT_KINDS = ["read-only", "full disk"]


def _fills(suffix: str):
    return lambda monkeypatch: fill_on_write(monkeypatch, lambda name: name.endswith(suffix))


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_bench_json(fault, request, monkeypatch, capfd):
    from hyperbones.jobs.timing import BenchRecord

    monkeypatch.setattr("hyperbones.jobs.bench.bench",
                        lambda *args, **kwargs: [BenchRecord("lbs", "dress", 1000, "cpu", 1, 0.1, 0.2)])
    folder, why = faulty_folder(fault, request, "bench", _fills(".json"))
    code, out, err = run(capfd, "bench", "--methods", "lbs", "--garments", "dress", "--quiet",
                         "--json", folder / "bench.json")
    assert_one_line(code, err, f"{folder / 'bench.json'}: cannot write: {why}")
    assert "| lbs | dress | 1000 |" in out  # the timings were printed before the file failed
    assert snapshot(folder) == {}


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_motion_out(fault, request, capfd):
    folder, why = faulty_folder(fault, request, "motion", _fills(".npz"))
    code, _, err = run(capfd, "motion", "walk", "--duration", "1", "--out", folder / "walk.npz")
    assert_one_line(code, err, f"{folder / 'walk.npz'}: cannot write: {why}")
    assert snapshot(folder) == {}


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_render(fault, request, capfd):
    folder, why = faulty_folder(fault, request, "render", _fills(".png"))  # the video is whole by then
    code, _, err = run(capfd, "render", "idle", "--duration", "0.5", "--blend-in", "0", "--size", "32", "--quiet",
                       "--out", folder / "idle.mp4")
    name = "idle.mp4" if fault == "read-only" else "idle_sheet.png"
    assert_one_line(code, err, f"{folder / name}: cannot write: {why}")
    assert snapshot(folder) == {}


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_garment_make(fault, request, capfd):
    folder, why = faulty_folder(fault, request, "garment", _fills(".obj"))
    code, _, err = run(capfd, "garment", "make", "tshirt", "--vertices", "1000", "--no-drape",
                       "--out", folder / "tshirt.obj")
    assert_one_line(code, err, f"{folder / 'tshirt.obj'}: cannot write: {why}")
    assert snapshot(folder) == {}


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_identity(fault, simulated, request, capfd):
    """torch.save: a full disk is a RuntimeError of torch's writer, named by the disk."""
    folder, why = faulty_folder(fault, request, "identity", torch_save_fails)
    code, _, err = run(capfd, "identity", "--garment", "tshirt", "--vertices", "1000", "--untrained",
                       "--uv-resolution", "32", "--out", folder / "dress.pt")
    assert_one_line(code, err, f"{folder / 'dress.pt'}: cannot write: {why}")
    assert snapshot(folder) == {}


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_export_writes_weights_and_summary_together(fault, request, capfd):
    folder, why = faulty_folder(fault, request, "export", _fills(".md"))  # the weights are written first
    code, _, err = run(capfd, "export", TEACHER, "--out", folder / "teacher.pt")
    wrote = folder if fault == "read-only" else folder / "teacher.md"
    assert_one_line(code, err, f"{wrote}: cannot write: {why}")
    assert snapshot(folder) == {}


def test_train_into_a_read_only_run_folder(tmp_path, read_only, capfd):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_TOML)
    code, _, err = run(capfd, "train", "--config", config, "--out", read_only, "--quiet")
    assert_one_line(code, err, str(read_only), DENIED)
    assert snapshot(read_only) == {}


def test_train_checkpoint_on_a_full_disk(tmp_path, monkeypatch, capfd):
    """The checkpoint cannot be saved: one line, and no half-written or temporary checkpoint.
    (The optimiser state staged before it is training.checkpoint's to tidy up.)"""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_TOML)
    torch_save_fails(monkeypatch, "checkpoint")
    run_dir = tmp_path / "run"
    code, _, err = run(capfd, "train", "--config", config, "--out", run_dir, "--quiet")
    assert_one_line(code, err, f"{run_dir / 'checkpoint.pt'}: cannot write: {NO_SPACE}")
    left = set(snapshot(run_dir))
    assert "checkpoint.pt" not in left and not [name for name in left if ".tmp" in name]
