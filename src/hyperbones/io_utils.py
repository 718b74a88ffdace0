"""Atomic file output (write to a temporary file beside the target, then rename) and safe,
version-checked loads of the tensor files the project writes."""

from __future__ import annotations

import contextlib
import os
import uuid
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it is removed.

    The temporary name keeps the suffix, so libraries that pick a format from it still work.
    A failure to write (read-only folder, full disk: an ``OSError``, or the ``RuntimeError``
    torch.save gives for one) is raised as a one-line ``OutputError`` naming ``path``; then
    ``path`` is as it was and the folders made for it are removed again.
    """
    from hyperbones.errors import output_error

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

