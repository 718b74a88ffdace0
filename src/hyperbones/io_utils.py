"""Atomic file output (write to a temporary file beside the target, then rename; a set of
outputs staged in a folder, then moved in), one-line errors for writes the place written to
refuses (read-only, full), and safe, version-checked loads of the tensor files the project
writes."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import uuid
from pathlib import Path
from typing import Iterator

from hyperbones.errors import OutputError


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it is removed.

    The temporary name keeps the suffix, so libraries that pick a format from it still work.
    A failure to write (read-only folder, full disk: an ``OSError``, or the ``RuntimeError``
    torch.save gives for one) is raised as a one-line ``OutputError`` naming ``path``; then
    ``path`` is as it was and the folders made for it are removed again.
    """
    path = Path(path)
    made = [folder for folder in (path.parent, *path.parent.parents) if not folder.exists()]
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    done = False
    try:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise output_error(path.parent, error) from None
        yield tmp
        os.replace(tmp, path)
        done = True
    except Exception as error:
        failure = output_error(path, error)
        if failure is None or failure is error:
            raise
        raise failure from error
    finally:
        with contextlib.suppress(OSError):  # the original error matters more
            tmp.unlink(missing_ok=True)
        if not done:
            for folder in made:  # deepest first; a folder something else wrote into stays
                with contextlib.suppress(OSError):
                    folder.rmdir()


def load_versioned(path: str | Path, what: str, version: int) -> dict:
    """A dict saved with ``torch.save`` holding ``"version": version``, loaded without running
    pickled code; a missing, unreadable or other-version file is an ``InputFileError`` naming it.
    what: the kind of file, for the message ("identity cache", "saved rollout")."""
    import torch

    from hyperbones.errors import InputFileError

    path = Path(path)
    if not path.exists():
        raise InputFileError(path, f"{what} not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises many kinds for a bad file
        raise InputFileError(path, f"not a hyperbones {what} ({type(error).__name__})") from None
    stored = payload.get("version") if isinstance(payload, dict) else None
    if type(stored) is not int or stored != version:  # a damaged file may hold a tensor there
        raise InputFileError(path, f"not a version-{version} hyperbones {what}")
    return payload


# Why a write fails for a reason of the place written to, not of the program.
_OUTPUT_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG, errno.EIO)
# torch.save to a path reports a failed open or write as a RuntimeError of its zip writer.
_TORCH_WRITER = re.compile(r"inline_container\.cc|PytorchStreamWriter|Parent directory .* does not exist")
LOW_SPACE = 1 << 20  # bytes: below this a folder counts as full


def is_output_fault(error: BaseException) -> bool:
    """Whether ``error`` says that the place written to refused the write (read-only, full, no
    permission), rather than that the program is wrong."""
    return isinstance(error, OSError) and error.errno in _OUTPUT_ERRNOS


def folder_problem(folder: str | Path) -> str | None:
    """Why files cannot be written into ``folder`` as the system says it (``os.strerror``:
    read-only file system, no space left, permission denied), or None when nothing shows."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        stats = os.statvfs(folder)
    except OSError:
        return None
    if stats.f_flag & os.ST_RDONLY:
        return os.strerror(errno.EROFS)
    if stats.f_bavail * stats.f_frsize < LOW_SPACE:
        return os.strerror(errno.ENOSPC)
    if not os.access(folder, os.W_OK):
        return os.strerror(errno.EACCES)
    return None


def output_error(path: str | Path, error: BaseException) -> OutputError | None:
    """``error``, raised while writing ``path``, as an ``OutputError`` naming ``path`` and the
    system's reason; None when it is no failure to write (a bug: raise it as it is)."""
    if isinstance(error, OutputError):
        return error
    if isinstance(error, OSError):
        return OutputError(path, f"cannot write: {_reason(error, Path(path).parent)}")
    if isinstance(error, RuntimeError) and _TORCH_WRITER.search(str(error)):
        told = re.search(r"strerror: ([^\n]+)", str(error))
        reason = told.group(1).strip() if told else folder_problem(Path(path).parent)
        return OutputError(path, f"cannot write: {reason or str(error).splitlines()[0]}")
    return None


def stated_reason(text: str, folder: str | Path) -> str | None:
    """Why a writer that reports in words (ffmpeg, USD) failed to write into ``folder``: the
    first system reason (``os.strerror``) its message names, else what ``folder_problem`` finds."""
    return next((os.strerror(c) for c in _OUTPUT_ERRNOS if os.strerror(c) in text), None) or folder_problem(folder)


def _reason(error: OSError, folder: Path) -> str:
    """The system's words for an OSError; for a broken pipe to a writer process (ffmpeg), the
    reason it stopped when its message or the folder shows one."""
    code = error.errno if error.errno is not None else next((a for a in error.args if isinstance(a, int)), None)
    if code == errno.EPIPE:
        return stated_reason(str(error), folder) or "the writing process stopped (broken pipe)"
    if error.strerror:
        return error.strerror
    return os.strerror(code) if code is not None else str(error) or type(error).__name__


@contextlib.contextmanager
def staged_outputs(out_dir: str | Path) -> Iterator[Path]:
    """Yield a hidden folder inside ``out_dir`` (made, parents too, when missing) to write a
    set of outputs into; when the block ends they all move into ``out_dir``, each replacing
    its namesake (a folder such as ``obj/`` as a whole), or, when it raises, none does.

    A failure to write (read-only folder, full disk) is an ``OutputError``. Either way nothing
    of the attempt stays behind: not the staging folder, not an ``out_dir`` made for it, not
    a file of the set, and an earlier run's outputs are then as they were.
    """
    out = Path(out_dir)
    made = [folder for folder in (out, *out.parents) if not folder.exists()]
    staging = out / f".staging-{uuid.uuid4().hex[:8]}"
    try:
        try:
            staging.mkdir(parents=True)
        except OSError as error:
            raise output_error(out, error) from None
        try:
            yield staging
        except OutputError as error:  # name the output, not its staged copy
            if staging not in error.path.parents:
                raise
            raise OutputError(out / error.path.relative_to(staging), error.problem) from None
        _move_in(staging, out)
        made = []
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        for folder in made:  # deepest first; one that holds anything else stays
            with contextlib.suppress(OSError):
                folder.rmdir()


def _move_in(staging: Path, out: Path) -> None:
    """Rename every entry of ``staging`` into ``out`` (hidden ones, writers' leftovers, stay).
    The entries they replace are moved aside first and back if a rename fails, so ``out``
    never holds half a set."""
    aside = staging / ".replaced"
    names = sorted(entry.name for entry in staging.iterdir() if not entry.name.startswith("."))
    done: list[str] = []
    try:
        aside.mkdir()
        for name in names:
            if os.path.lexists(out / name):
                os.replace(out / name, aside / name)
            done.append(name)
            os.replace(staging / name, out / name)
    except BaseException as error:
        for name in reversed(done):
            with contextlib.suppress(OSError):
                if not os.path.lexists(staging / name):  # the new one went in: take it out again
                    os.replace(out / name, staging / name)
                if os.path.lexists(aside / name):
                    os.replace(aside / name, out / name)
        if isinstance(error, OSError):
            raise output_error(out, error) from None
        raise
