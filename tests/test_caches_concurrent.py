"""Two processes building the same cached thing at once both succeed, get the same result, and
leave one valid entry per key; a reader racing a writer of an entry never sees a partial file.

The on-disk caches under ``HYPERBONES_CACHE_DIR``: draped garments (``garment.draped``,
``garments/``), training templates (``training.data.template_source``, ``templates/``) and
settled training garments (``training.data.draped_vertices``, ``training-drapes/``). (Anny's
own cache, which the anny library builds, is written by safetensors >= 0.8 to a temporary name
and renamed; pinned in pyproject.toml. Two cold builds at once were checked once by hand:
~1 GB each, too heavy for the suite.)"""

import os
import subprocess
import sys
import time
from pathlib import Path

import torch

VERTICES = 1000

# One process of the race: the body first (Anny's start-up varies between processes), then a
# barrier, so that both miss the cache and build every entry at the same time.
BUILD = """
import sys
import time
from pathlib import Path

import torch

from hyperbones.body import BodyShape, body_for
from hyperbones.garment.draped import draped_garment
from hyperbones.training.data import draped_vertices, template_source

out, me, other, vertices = Path(sys.argv[1]), sys.argv[2], sys.argv[3], int(sys.argv[4])
body = body_for(BodyShape())
(out / f"ready-{me}").touch()
while not (out / f"ready-{other}").exists():
    time.sleep(0.001)
garment, rest = draped_garment("tshirt", body, vertices=vertices)
source = template_source("tshirt", vertices, body)
settled = draped_vertices(source.garment, body, vertices)
torch.save({"draped": garment.vertices, "rest": rest, "faces": garment.faces, "template": source.garment.vertices,
            "skin_weights": source.skin_weights, "settled": settled}, out / f"result-{me}.pt")
"""

# One process of the Anny race: the barrier comes before the model's first construction.
# A writer that rewrites a cache entry the way a slow disk would let a concurrent builder do
# it: in pieces, with pauses, through the caches' own atomic write.
REWRITE = """
import io
import sys
import time
from pathlib import Path

import torch

from hyperbones.io_utils import atomic_path

path, times = Path(sys.argv[1]), int(sys.argv[2])
buffer = io.BytesIO()
torch.save(torch.load(path, weights_only=True), buffer)
data = buffer.getvalue()
piece = len(data) // 5 + 1
for _ in range(times):
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as file:
            for start in range(0, len(data), piece):
                file.write(data[start:start + piece])
                file.flush()
                time.sleep(0.01)
"""


def cache_files(cache: Path) -> dict[str, list[str]]:
    """Folder -> the names of the files in it, every file under ``cache``."""
    found: dict[str, list[str]] = {}
    for folder, _, names in os.walk(cache):
        for name in names:
            found.setdefault(str(Path(folder).relative_to(cache)), []).append(name)
    return found


def test_two_processes_build_the_same_entries_at_once(tmp_path):
    cache = tmp_path / "cache"
    script = tmp_path / "build.py"
    script.write_text(BUILD)
    env = dict(os.environ, OMP_NUM_THREADS="1", HYPERBONES_CACHE_DIR=str(cache))
    runs = [subprocess.Popen([sys.executable, str(script), str(tmp_path), me, other, str(VERTICES)], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for me, other in (("a", "b"), ("b", "a"))]
    for run in runs:
        _, stderr = run.communicate(timeout=600)
        assert run.returncode == 0, stderr[-3000:]

    first, second = (torch.load(tmp_path / f"result-{me}.pt", weights_only=True) for me in "ab")
    assert all(torch.equal(first[name], second[name]) for name in first)
    # One entry per key and no temporary file ("." names: atomic_path's); each entry holds what both got.
    files = cache_files(cache)
    assert sorted(files) == ["garments", "templates", "training-drapes"]
    assert all(len(names) == 1 and not names[0].startswith(".") for names in files.values()), files
    draped = torch.load(cache / "garments" / files["garments"][0], weights_only=True)
    assert torch.equal(draped["vertices"], first["draped"]) and torch.equal(draped["rest_vertices"], first["rest"])
    template = torch.load(cache / "templates" / files["templates"][0], weights_only=True)
    assert torch.equal(template["vertices"], first["template"])
    assert torch.equal(template["skin_weights"], first["skin_weights"])
    settled = torch.load(cache / "training-drapes" / files["training-drapes"][0], weights_only=True)
    assert torch.equal(settled, first["settled"])


def test_a_reader_racing_writers_never_sees_a_partial_entry(tmp_path, body, monkeypatch):
    """``draped_garment`` reads its entry over and over while two processes rewrite it slowly
    (the entry made without the drape, which is not what is tested here)."""
    from types import SimpleNamespace

    from hyperbones.garment import draped
    from hyperbones.garment.draped import draped_garment

    monkeypatch.setenv("HYPERBONES_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(draped, "drape", lambda garment, body, rest=None: (
        garment, SimpleNamespace(converged=True, rest_vertices=garment.vertices)))
    garment, rest = draped_garment("tshirt", body, vertices=VERTICES)
    monkeypatch.undo()
    monkeypatch.setenv("HYPERBONES_CACHE_DIR", str(tmp_path / "cache"))
    (entry,) = (tmp_path / "cache" / "garments").iterdir()
    script = tmp_path / "rewrite.py"
    script.write_text(REWRITE)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    writers = [subprocess.Popen([sys.executable, str(script), str(entry), "40"], env=env, stderr=subprocess.PIPE,
                                text=True) for _ in range(2)]
    reads, seen = 0, set()
    while any(writer.poll() is None for writer in writers):
        status = entry.stat()
        seen.add((status.st_ino, status.st_mtime_ns))  # inode numbers alone are reused by the filesystem
        again, again_rest = draped_garment("tshirt", body, vertices=VERTICES)
        assert torch.equal(again.vertices, garment.vertices) and torch.equal(again_rest, rest)
        reads += 1
        time.sleep(0.002)
    for writer in writers:
        assert writer.wait() == 0, writer.stderr.read()[-3000:]
    assert reads > 20 and len(seen) > 5  # the reads did meet the entry being replaced
    assert [p.name for p in entry.parent.iterdir()] == [entry.name]
