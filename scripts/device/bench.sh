#!/usr/bin/env bash
# The per-frame runtime's GPU benchmark (hyperbones.jobs.device_bench), in one call.
#
#   scripts/device/bench.sh --prepare        here: write the inputs to .device/bench (Anny, Warp, the drape)
#   scripts/device/bench.sh                  on the GPU machine: time them, table to $OUT/bench.md
#   scripts/device/bench.sh --cpu --quick    anywhere: the same job on the CPU, smallest case (the suite runs this)
#
# The device call: run(command="bash scripts/device/bench.sh", carry=[".device"], timeout_s=420).
# .device is ignored by git; what travels is the repository (~13 MB) and .device (~25 MB).
set -euo pipefail
cd "$(dirname "$0")/../.."
PYTHON="${PYTHON:-python3}"
FOLDER="${BENCH_FOLDER:-.device/bench}"
device=cuda quick="" prepare=""
for arg in "$@"; do
  case "$arg" in
    --cpu) device=cpu ;;
    --quick) quick=--quick ;;
    --prepare) prepare=1 ;;
    *) echo "bench.sh: unknown option $arg (--prepare, --cpu, --quick)" >&2; exit 2 ;;
  esac
done
export PYTHONPATH="src:$FOLDER/site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
if [ -n "$prepare" ]; then
  exec "$PYTHON" -m hyperbones.jobs.device_bench prepare --out "$FOLDER" ${BENCH_VERTICES:+--vertices "$BENCH_VERTICES"}
fi
if [ ! -f "$FOLDER/body.rig.pt" ]; then
  echo "bench.sh: $FOLDER holds no prepared inputs; run scripts/device/bench.sh --prepare first" >&2
  exit 2
fi
"$PYTHON" -m hyperbones.jobs.device_bench run --folder "$FOLDER" --device "$device" $quick \
  --out "${OUT:-$FOLDER}/bench.md"
