"""Training on a GPU machine, a few minutes a call: the pack prepared here, the run resumed there.

The project's GPU machines have Python with torch but neither Anny, Warp nor roma; a call
carries at most 64 MiB there (the repository's files and the paths it names), lasts at most
10 minutes, and brings back at most 8 files of under 16 MiB each from ``$OUT``. So a long run
goes in calls, its state committed between them:

- ``prepare`` (here) writes the phase's training pack (``hyperbones pack``) and a copy of roma;
- ``run`` (there) first runs a few steps into a scratch folder (``--smoke``: short rollouts,
  batches of 2), so that a step that cannot run on that device fails in seconds, not after
  minutes of rollouts; then it copies the run's committed state (``runs/device-<phase>/``)
  into ``$OUT/state``, resumes the torch-only trainer (``training.from_pack``) on it for a few
  minutes, checkpointing every minute so that a call cut short still brings back its last
  minute, logs to ``$OUT/train.log``, and ends with a summary: the TensorBoard log's medians
  (the log itself stays behind: each resume adds an event file, and ``$OUT`` brings back 8
  files) and whether the state will come back whole (``returned_problems``);
- ``size`` (here) says what such a call carries, against the limit.

``scripts/device/train.sh`` wraps all three and holds the layout (which pack, which config).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MIB = 2**20
TRAVEL_LIMIT = 64 * MIB  # what one call may carry, the repository's files included
TRAVEL_BUDGET = 60 * MIB  # the project's own limit: room for the state to grow between calls
RETURNED_FILE_LIMIT = 16 * MIB  # each file back from $OUT is under this
STATE_FILES = 6  # $OUT brings back 8 files: the state's, train.log, one to spare
CALL_SECONDS = 600  # the longest a device command may run
STARTUP_SECONDS = 120  # Python, torch, CUDA and the pack loaded, and the last save, around the minutes trained
RETURNED_NAME = re.compile(r"[A-Za-z0-9._-]+")
TRAINER = "hyperbones.training.from_pack"  # the torch-only trainer, run as ``python -m``


def prepare(config: str, pack: str | Path, site: str | Path, quick: bool = False) -> int:
    """Write ``config``'s training pack to ``pack`` (needs Anny and Warp) and roma into ``site``;
    the exit status of ``hyperbones pack``."""
    from hyperbones.jobs.device_bench import copy_package
    from hyperbones.training.config import apply_overrides, load_config
    from hyperbones.training.pack import DEFAULT_BODIES, QUICK_BODIES, QUICK_DATA, build_pack

    settings = apply_overrides(load_config(config), QUICK_DATA if quick else ())
    summary = build_pack(settings, pack, bodies=QUICK_BODIES if quick else DEFAULT_BODIES,
                         progress=lambda text: print(f"packing {text}", flush=True))
    print(f"wrote {pack} ({summary['bytes'] / MIB:.1f} MiB)")
    print(copy_package("roma", site))
    return 0


def has_state(folder: str | Path) -> bool:
    """Whether a run's state folder holds a state to resume (any file not hidden)."""
    folder = Path(folder)
    return folder.is_dir() and any(f.is_file() and not f.name.startswith(".") for f in folder.rglob("*"))


def returned_problems(state: str | Path) -> list[str]:
    """Why the state written into ``$OUT/state`` would not come back whole from a device call
    (too many files, one too large, too deep, an odd name); empty when it will."""
    state = Path(state)
    files = sorted(f for f in state.rglob("*") if f.is_file())
    problems = []
    if len(files) > STATE_FILES:
        problems.append(f"{len(files)} files, over {STATE_FILES} ($OUT brings back 8 with train.log)")
    for file in files:
        name = file.relative_to(state).as_posix()
        if file.stat().st_size >= RETURNED_FILE_LIMIT:
            problems.append(f"{name} is {file.stat().st_size / MIB:.1f} MiB, not under 16")
        if len(file.relative_to(state).parts) > 2:
            problems.append(f"{name} is more than 2 folders below $OUT")
        if not all(RETURNED_NAME.fullmatch(part) for part in file.relative_to(state).parts):
            problems.append(f"{name}: names travel in letters, digits, '.', '_' and '-' alone")
    return problems


def _tree_bytes(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())


def repository_bytes(root: str | Path = ".", leave_out: Path | None = None) -> int:
    """Bytes of the files a device call sends of the repository: tracked, and untracked but not
    ignored, as in the working tree; those under ``leave_out`` apart."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=root,
                            capture_output=True, check=True).stdout.decode().split("\0")
    skip = leave_out.resolve() if leave_out else None
    total = 0
    for name in filter(None, listed):
        path = Path(root, name)
        if path.is_file() and not path.is_symlink() and not (skip and path.resolve().is_relative_to(skip)):
            total += path.stat().st_size
    return total


def run_call(phase: str, carry: list[str], minutes: float) -> str:
    """The device tool's call that trains ``phase`` with these carried paths."""
    timeout = min(CALL_SECONDS, round(minutes * 60) + STARTUP_SECONDS)
    listed = ", ".join(f'"{path}"' for path in carry)
    return f'run(command="bash scripts/device/train.sh {phase}", carry=[{listed}], timeout_s={timeout})'


def size(phase: str, carry: list[str], state: str | Path, minutes: float) -> int:
    """Print what a device call for ``phase`` carries, in MiB; 1 over the project's budget."""
    state = Path(state)
    parts = [("repository (tracked + untracked, not ignored)", repository_bytes(".", state))]
    parts += [(path, _tree_bytes(Path(path))) for path in carry]
    saved = _tree_bytes(state) if has_state(state) else 0
    parts.append((f"{state} (the run's state{'' if saved else ': none, it starts afresh'})", saved))
    total = sum(size for _, size in parts)
    width = max(len(what) for what, _ in parts)
    for what, bytes_ in parts:
        print(f"{what:<{width}}  {bytes_ / MIB:6.1f} MiB")
    print(f"{'total':<{width}}  {total / MIB:6.1f} MiB of {TRAVEL_LIMIT // MIB} (budget {TRAVEL_BUDGET // MIB})")
    print(run_call(phase, carry, minutes))
    ignored = subprocess.run(["git", "check-ignore", "-q", str(state)], capture_output=True).returncode == 0
    if saved and ignored:
        print(f"train.sh: {state} is ignored by git, so it would not travel: commit it or carry it", file=sys.stderr)
        return 1
    if total > TRAVEL_BUDGET:
        print(f"train.sh: {total / MIB:.1f} MiB would travel, over the {TRAVEL_BUDGET // MIB} MiB budget",
              file=sys.stderr)
        return 1
    return 0


def run(config: str, pack: str | Path, state: str | Path, out: str | Path, device: str, minutes: float,
        quick: bool = False, extra: list[str] | None = None, trainer: str = TRAINER) -> int:
    """Resume (or start) the run of ``state`` in ``out``/state for ``minutes``, logging to
    ``out``/train.log; the trainer's exit status, else 3 when the state would not come back whole.
    ``extra``: more of the trainer's options; ``trainer``: its module."""
    out, state = Path(out), Path(state)
    work = out / "state"
    if work.exists() and any(work.iterdir()):
        print(f"train.sh: {work} already holds files: empty it or set OUT to another folder", file=sys.stderr)
        return 2
    work.mkdir(parents=True, exist_ok=True)
    resume = has_state(state)
    if resume:
        shutil.copytree(state, work, dirs_exist_ok=True)
    trainer_command = [sys.executable, "-m", trainer, "--pack", str(pack), "--config", config, "--device", device]
    command = [*trainer_command, "--out", str(work), "--minutes", f"{minutes:g}", "--checkpoint-minutes", "1",
               *(["--resume"] if resume else []), *(["--quick"] if quick else []), *(extra or [])]
    log = out / "train.log"
    start = time.monotonic()
    with log.open("a") as sink:
        _say(sink, f"{time.strftime('%Y-%m-%d %H:%M:%S')} {config} on {device}: "
                   f"{f'resuming {state}' if resume else 'a fresh run'}, {minutes:g} min")
        if not quick:  # --quick is itself this check
            with tempfile.TemporaryDirectory() as scratch:
                smoke = _stream([*trainer_command, "--out", scratch, "--smoke", *(extra or [])], sink)
            if smoke:
                _say(sink, f"\n== summary: the smoke check failed (exit {smoke}) after "
                           f"{time.monotonic() - start:.0f} s; the run was not started")
                return smoke
            _say(sink, f"smoke check passed in {time.monotonic() - start:.0f} s")
        returncode = _stream(command, sink)
        _say(sink, _log_summary(work / "tensorboard"))
        shutil.rmtree(work / "tensorboard", ignore_errors=True)  # summed up above; a new event file per call
        problems = returned_problems(work)
        files = sorted(f for f in work.rglob("*") if f.is_file())
        lines = ["", f"== summary: trainer exit {returncode} after {time.monotonic() - start:.0f} s; "
                     f"{len(files)} state files, {sum(f.stat().st_size for f in files) / MIB:.1f} MiB in {work}"]
        lines += [f"   {f.relative_to(work)}  {f.stat().st_size / MIB:.2f} MiB" for f in files]
        lines += [f"   WILL NOT COME BACK WHOLE: {problem}" for problem in problems]
        if files and not problems:
            lines.append(f"   commit it: rm -rf {state} && cp -r --no-preserve=mode FILES_AT/state {state} "
                         f"&& git add -A {state}")
        _say(sink, "\n".join(lines))
    return returncode or (3 if problems else 0)


def _stream(command: list[str], sink) -> int:
    """Run ``command``, its output to stdout and ``sink`` line by line; its exit status."""
    _say(sink, f"$ {' '.join(command)}")
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as process:
        for line in process.stdout:
            sys.stdout.write(line)
            sink.write(line)
            sink.flush()
    return process.returncode


def _log_summary(log_dir: Path) -> str:
    """The run's TensorBoard log as a table of medians (``training.summary``), for train.log."""
    from hyperbones.training.summary import read_log, training_summary

    if not log_dir.exists():
        return "(no TensorBoard log)"
    return "training log (medians per stretch of steps):\n" + training_summary(read_log(log_dir))


def _say(sink, text: str) -> None:
    print(text, flush=True)
    sink.write(text + "\n")
    sink.flush()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hyperbones.jobs.device_train", description=__doc__.split("\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    prep = verbs.add_parser("prepare", help="write the phase's training pack and roma (needs Anny and Warp)")
    prep.add_argument("--config", required=True)
    prep.add_argument("--pack", required=True)
    prep.add_argument("--site", required=True, help="folder to copy roma into (PYTHONPATH on the device)")
    prep.add_argument("--quick", action="store_true", help="a small pack, for the CPU check")
    measure = verbs.add_parser("size", help="what a device call carries, in MiB")
    measure.add_argument("--phase", required=True)
    measure.add_argument("--carry", nargs="+", required=True, help="the paths the call carries")
    measure.add_argument("--state", required=True, help="the run's committed state folder")
    measure.add_argument("--minutes", type=float, default=8)
    go = verbs.add_parser("run", allow_abbrev=False,  # the trainer's own options pass through, unabbreviated
                          help="resume the run and train for --minutes (torch alone); other options go to the trainer")
    go.add_argument("--config", required=True)
    go.add_argument("--pack", required=True)
    go.add_argument("--state", required=True, help="the run's committed state folder (read, never written)")
    go.add_argument("--out", required=True, help="where state/ and train.log go ($OUT on the device)")
    go.add_argument("--device", default="cuda")
    go.add_argument("--minutes", type=float, default=8)
    go.add_argument("--quick", action="store_true")
    args, extra = parser.parse_known_args(argv)
    if extra and args.verb != "run":
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if args.verb == "prepare":
        return prepare(args.config, args.pack, args.site, args.quick)
    if args.verb == "size":
        return size(args.phase, args.carry, args.state, args.minutes)
    return run(args.config, args.pack, args.state, args.out, args.device, args.minutes, args.quick, extra)


if __name__ == "__main__":
    sys.exit(main())
