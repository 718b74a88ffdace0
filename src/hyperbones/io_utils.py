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
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


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
    if not isinstance(payload, dict) or payload.get("version") != version:
        raise InputFileError(path, f"not a version-{version} hyperbones {what}")
    return payload

