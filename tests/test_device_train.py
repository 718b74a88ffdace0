"""The GPU training job (``scripts/device/train.sh``, ``hyperbones.jobs.device_train``): it says
what a device call carries and refuses one over budget, names what is missing in one line,
resumes a committed state into ``$OUT/state`` and says whether that state will come back whole;
and, once the torch-only trainer is there, runs end to end on the CPU."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hyperbones.jobs.device_train import MIB, has_state, returned_problems, run

ROOT = Path(__file__).resolve().parents[1]


def train_sh(*args: str, **env: str | Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHON": sys.executable, **{key: str(value) for key, value in env.items()}}
    return subprocess.run(["bash", str(ROOT / "scripts/device/train.sh"), *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture
def prepared(tmp_path):
    """A pack folder as ``--prepare`` leaves it (a stand-in pack of 3 MiB) and a run state of 2 MiB."""
    folder, state = tmp_path / "train", tmp_path / "runs" / "device-teacher"
    (folder / "site" / "roma").mkdir(parents=True)
    (folder / "site" / "roma" / "__init__.py").write_text("")
    (folder / "teacher.pack.pt").write_bytes(os.urandom(3 * MIB))
    state.mkdir(parents=True)
    (state / "checkpoint.pt").write_bytes(os.urandom(2 * MIB))
    return folder, state


def test_the_dry_run_says_what_travels(prepared):
    folder, state = prepared
    done = train_sh("--dry-run", "teacher", TRAIN_FOLDER=folder, TRAIN_STATE=state)
    assert done.returncode == 0, done.stderr
    sizes = {line.rsplit(None, 2)[0].split(" (")[0]: float(line.split()[-2])
             for line in done.stdout.splitlines() if line.endswith(" MiB")}
    assert sizes[str(folder / "teacher.pack.pt")] == 3.0 and sizes[str(state)] == 2.0
    assert 1 < sizes["repository"] < 60  # the shipped weights at least, and what the project keeps under budget
    total = float(done.stdout.split("total")[1].split()[0])
    assert abs(total - sum(sizes.values())) < 0.2
    assert (f'run(command="bash scripts/device/train.sh teacher", carry=["{folder}/site", '
            f'"{folder}/teacher.pack.pt"], timeout_s=600)') in done.stdout


def test_the_dry_run_refuses_a_call_over_budget(prepared):
    folder, state = prepared
    with (folder / "teacher.pack.pt").open("r+b") as pack:
        pack.truncate(61 * MIB)  # sparse: its size counts, not its blocks
    done = train_sh("--dry-run", "teacher", TRAIN_FOLDER=folder, TRAIN_STATE=state)
    assert done.returncode == 1 and "over the 60 MiB budget" in done.stderr


@pytest.mark.parametrize("args, message", [
    (("--gpu", "teacher"), "train.sh: unknown option --gpu"),
    (("--cpu",), "train.sh: which PHASE: teacher or hyperbones?"),
    (("teacher", "hyperbones"), "train.sh: one PHASE only"),
    (("hyperbones",), "hyperbones.pack.pt missing: run scripts/device/train.sh --prepare hyperbones first"),
    (("--dry-run", "teacher"), "teacher.pack.pt missing: run scripts/device/train.sh --prepare teacher first"),
])
def test_the_job_says_what_is_wrong_in_one_line(tmp_path, args, message):
    done = train_sh(*args, TRAIN_FOLDER=tmp_path / "empty")
    assert done.returncode == 2 and message in done.stderr and done.stderr.count("\n") == 1, done.stderr
    assert not done.stdout


def test_a_run_never_writes_over_an_earlier_state(prepared, tmp_path):
    folder, state = prepared
    (tmp_path / "out" / "state").mkdir(parents=True)
    (tmp_path / "out" / "state" / "checkpoint.pt").write_bytes(b"earlier")
    done = train_sh("--cpu", "teacher", TRAIN_FOLDER=folder, TRAIN_STATE=state, OUT=tmp_path / "out")
    assert done.returncode == 2 and "already holds files" in done.stderr
    assert (tmp_path / "out" / "state" / "checkpoint.pt").read_bytes() == b"earlier"


FAKE_TRAINER = textwrap.dedent("""
    import argparse, os, pathlib
    parser = argparse.ArgumentParser()
    for name in ("--pack", "--config", "--out", "--minutes", "--device", "--checkpoint-minutes", "--files"):
        parser.add_argument(name)
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    out = pathlib.Path(args.out)
    if args.smoke:
        (out / "smoke.pt").write_bytes(b"x")
        print(f"smoke step on {args.device}")
        raise SystemExit(int(os.environ.get("SMOKE_EXIT", "0")))
    step = int((out / "step.txt").read_text()) if args.resume else 0
    for index in range(int(args.files or 2) - 1):
        (out / f"part{index}.pt").write_bytes(b"x")
    (out / "step.txt").write_text(str(step + 10))
    print(f"trained {args.config} on {args.device} for {args.minutes} min: step {step} -> {step + 10}")
""")


def test_a_run_resumes_the_committed_state_and_says_what_comes_back(tmp_path, monkeypatch):
    """The job around the trainer, with a stand-in trainer: fresh, then resumed from what the
    first call brought back (the committed folder left as it was), then a state too many files."""
    (tmp_path / "fake_trainer.py").write_text(FAKE_TRAINER)
    monkeypatch.setenv("PYTHONPATH", f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    committed = tmp_path / "runs" / "device-teacher"
    common = dict(config="configs/teacher.toml", pack=tmp_path / "teacher.pack.pt", state=committed, device="cpu",
                  minutes=0.25, trainer="fake_trainer")
    assert not has_state(committed)
    assert run(out=tmp_path / "call1", **common) == 0
    log = (tmp_path / "call1" / "train.log").read_text()
    assert "a fresh run" in log and "step 0 -> 10" in log and "commit it:" in log
    assert log.index("smoke step on cpu") < log.index("smoke check passed") < log.index("step 0 -> 10")
    assert not (tmp_path / "call1" / "state" / "smoke.pt").exists()  # the smoke's folder is a scratch one
    committed.parent.mkdir()
    (tmp_path / "call1" / "state").rename(committed)
    assert has_state(committed)
    assert run(out=tmp_path / "call2", **common) == 0
    log = (tmp_path / "call2" / "train.log").read_text()
    assert f"resuming {committed}" in log and "--resume" in log and "step 10 -> 20" in log
    assert (committed / "step.txt").read_text() == "10"  # the committed state is read, never written
    assert run(out=tmp_path / "call3", extra=["--files", "7"], **common) == 3
    assert "WILL NOT COME BACK WHOLE: 7 files, over 6" in (tmp_path / "call3" / "train.log").read_text()


def test_a_failing_smoke_check_stops_the_job_before_the_run(tmp_path, monkeypatch):
    (tmp_path / "fake_trainer.py").write_text(FAKE_TRAINER)
    monkeypatch.setenv("PYTHONPATH", f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    monkeypatch.setenv("SMOKE_EXIT", "1")
    assert run("configs/teacher.toml", tmp_path / "teacher.pack.pt", tmp_path / "committed", tmp_path / "call",
               "cpu", 0.25, trainer="fake_trainer") == 1
    log = (tmp_path / "call" / "train.log").read_text()
    assert "the smoke check failed (exit 1)" in log and "step 0 -> 10" not in log
    assert not any((tmp_path / "call" / "state").iterdir())


def test_returned_problems(tmp_path):
    state = tmp_path / "state"
    (state / "tensorboard" / "deeper").mkdir(parents=True)
    (state / "checkpoint.pt").write_bytes(b"x")
    (state / "tensorboard" / "events.1").write_bytes(b"x")
    assert returned_problems(state) == []
    with (state / "big.pt").open("wb") as big:
        big.truncate(16 * MIB)
    (state / "tensorboard" / "deeper" / "events.2").write_bytes(b"x")
    (state / "odd name.pt").write_bytes(b"x")
    problems = " | ".join(returned_problems(state))
    assert "big.pt is 16.0 MiB, not under 16" in problems
    assert "tensorboard/deeper/events.2 is more than 2 folders below $OUT" in problems
    assert "odd name.pt: names travel in letters" in problems and "files, over" not in problems


@pytest.mark.parametrize("phase", ["teacher", "hyperbones"])
def test_the_device_training_runs_on_the_cpu(tmp_path, phase):
    """--prepare --quick, then two calls of --cpu --quick: the second resumes what the first
    brought back, and each brings back a state that comes back whole."""
    folder, committed = tmp_path / "train", tmp_path / "runs" / f"device-{phase}"
    committed.parent.mkdir()
    done = train_sh("--prepare", "--quick", phase, TRAIN_FOLDER=folder)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (folder / f"{phase}.pack.pt").stat().st_size < 16 * MIB and (folder / "site/roma/__init__.py").exists()
    for call in ("call1", "call2"):
        done = train_sh("--cpu", "--quick", phase, TRAIN_FOLDER=folder, TRAIN_STATE=committed, OUT=tmp_path / call)
        assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
        assert returned_problems(tmp_path / call / "state") == [] and has_state(tmp_path / call / "state")
        assert "commit it:" in (tmp_path / call / "train.log").read_text().splitlines()[-1]
        if call == "call1":
            (tmp_path / call / "state").rename(committed)
    assert f"resuming {committed}" in (tmp_path / "call2" / "train.log").read_text()


def test_the_gpu_phase2_settings_make_a_valid_config_for_the_run_and_its_smoke_check():
    """train.sh's GPU_PHASE2 overrides on the phase-2 config, as the run takes them and as its
    smoke check does (``--smoke`` then sets one frame a step)."""
    import re
    import shlex

    from hyperbones.training.config import apply_overrides, load_config
    from hyperbones.training.from_pack import QUICK_JOINT

    script = (ROOT / "scripts/device/train.sh").read_text()
    sets = shlex.split(re.search(r"^GPU_PHASE2=\((.*?)\)", script, re.S | re.M).group(1))
    config_path = re.search(r"^HYPERBONES_CONFIG=(\S+)", script, re.M).group(1)
    overrides = [value.removeprefix("--set=") for value in sets]
    assert overrides and all(value != option for value, option in zip(overrides, sets))  # each one --set=...
    run_config = apply_overrides(load_config(ROOT / config_path), overrides)
    assert run_config.joint.frames_per_step > run_config.joint.frames_per_rollout > 1
    smoke = apply_overrides(run_config, QUICK_JOINT)
    assert smoke.joint.frames_per_step == smoke.joint.frames_per_rollout == 1


def test_the_throughput_call_names_a_missing_pack_in_one_line(tmp_path):
    """scripts/device/throughput.sh stops before any Python when a pack is not prepared."""
    done = subprocess.run(["bash", str(ROOT / "scripts/device/throughput.sh")], cwd=ROOT, capture_output=True,
                          text=True, timeout=60, env={**os.environ, "TRAIN_FOLDER": str(tmp_path), "OUT": str(tmp_path)})
    assert done.returncode == 2
    assert done.stderr.strip() == (f"throughput.sh: {tmp_path}/teacher.pack.pt missing: "
                                   "run scripts/device/train.sh --prepare teacher first")
    assert not (tmp_path / "throughput.md").exists()
