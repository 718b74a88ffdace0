#!/usr/bin/env bash
# Keeps one CPU core adding teacher rollouts to #28's bank, draped and carried starts in turns,
# until it is stopped; run it again (same arguments) to go on where it stopped.
#
#   nohup bash scripts/bank.sh [BANK] [DRAPED_SEED] [CARRIED_SEED] >> BANK.log 2>&1 &
#
# BANK defaults to ~/.cache/hyperbones/bank (outside the work tree, which is laid anew each
# session); the seeds to 40 and 42 (another process sharing the bank takes two others).
# Pause with `pkill -STOP -f "hyperbones.cli rollouts"` and `pkill -CONT ...`; sum it up with
# `python scripts/bank_draws.py BANK`. The teacher runs compiled, and in bfloat16 where the
# processor has bfloat16 units (docs/experiments/2026-11-30-bfloat16-bank.md).
set -euo pipefail
bank=$(realpath -m "${1:-$HOME/.cache/hyperbones/bank}")  # before the cd: a relative BANK is the caller's
cd "$(dirname "$0")/.."
draped_seed=${2:-40}
carried_seed=${3:-42}
python=${PYTHON:-.venv/bin/python}
flags=(--config configs/hyperbones-draped.toml --out "$bank" --count 5 --compile --quiet)
if "$python" -c "from hyperbones.devices import cpu_has_bfloat16 as has; raise SystemExit(not has())"; then
  flags+=(--bfloat16)
fi
mkdir -p "$bank"
export OMP_NUM_THREADS=1
while true; do
  "$python" -m hyperbones.cli rollouts "${flags[@]}" --seed "$draped_seed" --drape
  "$python" -m hyperbones.cli rollouts "${flags[@]}" --seed "$carried_seed" --no-drape
done
