"""Shared fixtures: one Anny body per test session, and the ../shared data when present."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# Draped garments are cached on disk; tests use their own cache, never the user's.
os.environ["HYPERBONES_CACHE_DIR"] = tempfile.mkdtemp(prefix="hyperbones-test-cache-")


SHARED = Path(__file__).resolve().parents[2] / "shared"
CMU_DIR = SHARED / "data" / "mocap" / "cmu"


def cmu_clip(name: str) -> Path:
    """Path of a CMU clip in ../shared, skipping the test when the data is absent."""
    path = CMU_DIR / f"{name}.bvh"
    if not path.exists():
        pytest.skip(f"../shared/data/mocap/cmu/{name}.bvh not found: the shared data folder is absent")
    return path


@pytest.fixture(scope="session")
def body():
    """The default Anny body (builds Anny's cache on a fresh machine, about a minute)."""
    from hyperbones.body import BodyShape, body_for

    return body_for(BodyShape())
