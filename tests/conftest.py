"""Shared fixtures: one Anny body per test session, and the ../shared data when present."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# Draped garments are cached on disk; tests use their own cache, never the user's. The xdist
# workers of one run share theirs (its entries are written atomically), so a drape is made once.
if os.environ.get("PYTEST_XDIST_TESTRUNUID"):
    _cache = Path(tempfile.gettempdir()) / f"hyperbones-test-cache-{os.environ['PYTEST_XDIST_TESTRUNUID']}"
    _cache.mkdir(exist_ok=True)
    os.environ["HYPERBONES_CACHE_DIR"] = str(_cache)
else:
    os.environ["HYPERBONES_CACHE_DIR"] = tempfile.mkdtemp(prefix="hyperbones-test-cache-")

# Under pytest-xdist (pyproject's ``-n``) the workers share the cores: each gets its share of
# threads (torch's, and those of the commands a test starts), not all of them each.
if os.environ.get("PYTEST_XDIST_WORKER_COUNT"):
    _threads = str(max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])))
    os.environ.setdefault("OMP_NUM_THREADS", _threads)
    os.environ.setdefault("MKL_NUM_THREADS", _threads)
    os.environ.setdefault("NUMBA_NUM_THREADS", _threads)
    import torch

    torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


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
