"""Errors that the command line reports as one line, without a traceback."""

from __future__ import annotations

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
