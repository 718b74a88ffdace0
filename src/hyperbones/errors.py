"""Errors that the command line reports as one line, without a traceback."""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path


class HyperbonesError(Exception):
    """Base class for problems caused by the user's input or environment.

    The message is a single line meant for the user; the CLI prints it as
    ``hyperbones: error: <message>`` and exits with status 2.
    """


class InputFileError(HyperbonesError):
    """A file the user gave cannot be used; the message names the file and the problem."""

    def __init__(self, path: str | Path, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ParameterError(HyperbonesError):
    """A command-line or API parameter is invalid (unknown key, out of range, ...)."""


class OutputError(HyperbonesError):
    """An output cannot be written (read-only folder, full disk, ...); the message names the
    file or folder and the problem. The writer that raises it has removed what it wrote."""

    def __init__(self, path: str | Path, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


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
