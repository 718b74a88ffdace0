#!/usr/bin/env bash
# Both training phases' episode-steps per second on the GPU machine, in one call: #27's last
# measurement (target: 100x this project's CPU trainer). Each phase has its own time cap, so a
# slow size costs its phase, not the call; the tables go to stdout and $OUT/throughput.md.
#
#   here:  PYTHON=.venv/bin/python bash scripts/device/train.sh --prepare teacher   (and --prepare hyperbones)
#   there: run(command="bash scripts/device/throughput.sh",
#              carry=[".device/train/site", ".device/train/teacher.pack.pt", ".device/train/hyperbones.pack.pt"],
#              timeout_s=420)
#   anywhere: DEVICE=cpu PHASE1_BATCHES=4 PHASE2_SIZES=4/1 PHASE2_CACHE=4 bash scripts/device/throughput.sh   (the CPU's side)
#
# DEVICE, PHASE1_BATCHES, PHASE1_CONFIG, PHASE2_SIZES and each phase's cap (PHASE1_SECONDS, PHASE2_SECONDS)
# change what runs; PHASE1_STEPS, PHASE2_STEPS and PHASE2_CACHE reach the two scripts; QUICK=1 reads the
# packs of --prepare --quick (a check on this machine, in minutes).
set -uo pipefail
cd "$(dirname "$0")/../.."
PYTHON="${PYTHON:-python3}"
FOLDER="${TRAIN_FOLDER:-.device/train}"
DEVICE="${DEVICE:-cuda}"
PHASE1_BATCHES="${PHASE1_BATCHES:-16 64 256}"
PHASE2_SIZES="${PHASE2_SIZES:-4/1 64/8 256/8 512/16}"
export PYTHONPATH="src:$FOLDER/site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
report="${OUT:-/tmp}/throughput.md"
quick=$([ -n "${QUICK:-}" ] && echo --quick || true)
mkdir -p "$(dirname "$report")"
for phase in teacher hyperbones; do
  [ -f "$FOLDER/$phase.pack.pt" ] ||
    { echo "throughput.sh: $FOLDER/$phase.pack.pt missing: run scripts/device/train.sh --prepare $phase first" >&2; exit 2; }
done
{
  echo "# Training throughput, $(date -u +%Y-%m-%dT%H:%MZ)"
  "$PYTHON" -c "import torch; print('torch', torch.__version__, '|', torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'no CUDA')"
  echo
  # -k: a size still running at its cap gets a second to print what it has measured.
  timeout -k 5 "${PHASE1_SECONDS:-170}" "$PYTHON" scripts/device/phase1_steps.py "$FOLDER/teacher.pack.pt" "$DEVICE" $PHASE1_BATCHES \
    --config "${PHASE1_CONFIG:-configs/teacher.toml}" $quick \
    || echo "(phase 1 stopped: exit $?)"
  echo
  echo "phase 2, configs/hyperbones-small.toml, $DEVICE"
  timeout -k 5 "${PHASE2_SECONDS:-200}" "$PYTHON" scripts/device/phase2_steps.py "$FOLDER/hyperbones.pack.pt" "$DEVICE" $PHASE2_SIZES $quick \
    || echo "(phase 2 stopped: exit $?)"
} 2>&1 | tee "$report"
