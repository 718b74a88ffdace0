"""The GPU benchmark job runs end to end on the CPU (``scripts/device/bench.sh --cpu --quick``),
from inputs prepared here, so it is ready the day a GPU machine is lent."""

import os
import subprocess
import sys
from pathlib import Path

from hyperbones.jobs.device_bench import prepare, run, runtime_label
from hyperbones.models.loading import hyperbones_payload
from hyperbones.runtime.simulator import runtime_config_of

ROOT = Path(__file__).resolve().parents[1]


def test_the_device_bench_runs_on_the_cpu(tmp_path, body):
    folder = tmp_path / "bench"
    written = prepare(folder, vertices=(1000,))
    assert (folder / "dress-1000.identity.pt") in written and (folder / "site" / "roma" / "__init__.py").exists()
    size = sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())
    assert size < 16 * 2**20  # travels with the repository in one device call (64 MiB in all)
    env = {**os.environ, "PYTHON": sys.executable, "BENCH_FOLDER": str(folder), "OUT": str(tmp_path / "out")}
    done = subprocess.run(["bash", str(ROOT / "scripts/device/bench.sh"), "--cpu", "--quick"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    table = (tmp_path / "out" / "bench.md").read_text()
    rows = [line.split("|")[1:-1] for line in table.splitlines() if line.startswith("| dress")]
    shipped = runtime_label(runtime_config_of(hyperbones_payload(None, "cpu", whole=False)))
    assert [(r[2].strip(), int(r[3])) for r in rows] == [("Module A @ 64²", 1), ("Module A @ 64²", 2), (shipped, 1)]
    assert all(float(r[5]) > 0 and float(r[6]) > 0 for r in rows)
    assert float(rows[1][6]) <= float(rows[1][5])  # per character: the batch's frame shared by two
    # Out of job time: every row is listed, none timed (the job ends in a known time).
    late = run(folder, "cpu", quick=True, seconds=0.0)
    assert len(late) == 3 and all(row.ms_per_frame is None and row.missing == "not timed (job time)" for row in late)


def test_the_device_bench_says_what_is_missing(tmp_path):
    env = {**os.environ, "PYTHON": sys.executable, "BENCH_FOLDER": str(tmp_path / "empty")}
    done = subprocess.run(["bash", str(ROOT / "scripts/device/bench.sh"), "--cpu"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--prepare first" in done.stderr
    done = subprocess.run(["bash", str(ROOT / "scripts/device/bench.sh"), "--gpu"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "unknown option --gpu" in done.stderr
