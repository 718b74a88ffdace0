#!/usr/bin/env bash
# Training on the GPU machine (hyperbones.jobs.device_train), about 8 minutes a call, the run's
# state committed in runs/device-PHASE/ between calls. PHASE: teacher (configs/teacher.toml) or
# hyperbones (phase 2, $HYPERBONES_CONFIG below).
#
#   scripts/device/train.sh --prepare PHASE       here: the phase's pack and roma into .device/train (Anny, Warp;
#                                                 PYTHON=.venv/bin/python: the Python that has them, python3 by default)
#   scripts/device/train.sh --dry-run PHASE       here: what the call carries, in MiB; exit 1 over 60
#   scripts/device/train.sh PHASE                 on the GPU machine: resume, train, state to $OUT/state
#   scripts/device/train.sh --cpu --quick PHASE   anywhere: the same job on the CPU, for seconds (the suite runs this)
#
# The device call (--dry-run prints it; .device/bench is left behind, only this phase's pack travels):
#   run(command="bash scripts/device/train.sh teacher",
#       carry=[".device/train/site", ".device/train/teacher.pack.pt"], timeout_s=600)
# Then commit what came back (files_at: the reply's folder), and the next call goes on from it:
#   rm -rf runs/device-teacher && cp -r --no-preserve=mode FILES_AT/state runs/device-teacher
#   git add -A runs/device-teacher && git commit -m "Teacher on the GPU: N more minutes (step ...)"
# TRAIN_ARGS passes options to the trainer (e.g. TRAIN_ARGS="--batch 16"); TRAIN_FOLDER, TRAIN_STATE
# and TRAIN_MINUTES move the pack folder, the state folder and the minutes (the tests use them).
set -euo pipefail
cd "$(dirname "$0")/../.."
HYPERBONES_CONFIG=configs/hyperbones-small.toml
# Phase 2 on a GPU: Module A learns 64 cached frames a step, 8 from each of 8 rollouts (one batch through A,
# one body search), from a cache of 48 rollouts with one new every 8 steps. The whole cache is made before
# the first step: 48 fit one simulated batch of 64 with room for the drift check's refusals. The CPU keeps
# the config's 4 frames (docs/experiments/2026-11-28-phase2-frames-in-batches.md). Rollouts whose garment came
# off above the hips are refused too (docs/experiments/2026-11-29-garments-that-come-off.md); the config
# itself stays the shipped model's stage-2 recipe, which had no such check. So does the loss on A's edge lengths against
# C's, which validation preferred at 1e4 (docs/experiments/2026-11-30-edge-length-loss.md).
GPU_PHASE2=(--set=joint.frames_per_step=64 --set=joint.frames_per_rollout=8 --set=joint.cache_size=48
            --set=joint.refresh_every=8 --set=joint.max_detached_pct=10 --set=joint.edge_weight=10000)
PYTHON="${PYTHON:-python3}"
FOLDER="${TRAIN_FOLDER:-.device/train}"
mode=run device=cuda quick="" phase=""
for arg in "$@"; do
  case "$arg" in
    --prepare) mode=prepare ;;
    --dry-run) mode=size ;;
    --cpu) device=cpu ;;
    --quick) quick=--quick ;;
    teacher|hyperbones) [ -z "$phase" ] || { echo "train.sh: one PHASE only" >&2; exit 2; }; phase=$arg ;;
    *) echo "train.sh: unknown option $arg (--prepare, --dry-run, --cpu, --quick; PHASE teacher or hyperbones)" >&2
       exit 2 ;;
  esac
done
case "$phase" in
  teacher) config=configs/teacher.toml ;;
  hyperbones) config=$HYPERBONES_CONFIG ;;
  *) echo "train.sh: which PHASE: teacher or hyperbones?" >&2; exit 2 ;;
esac
pack="$FOLDER/$phase.pack.pt" state="${TRAIN_STATE:-runs/device-$phase}"
minutes="${TRAIN_MINUTES:-$([ -n "$quick" ] && echo 0.25 || echo 8)}"
export PYTHONPATH="src:$FOLDER/site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
job=("$PYTHON" -m hyperbones.jobs.device_train)
if [ $mode = prepare ]; then
  exec "${job[@]}" prepare --config "$config" --pack "$pack" --site "$FOLDER/site" $quick
fi
if [ ! -f "$pack" ]; then
  echo "train.sh: $pack missing: run scripts/device/train.sh --prepare $phase first" >&2
  exit 2
fi
if [ $mode = size ]; then
  exec "${job[@]}" size --phase "$phase" --carry "$FOLDER/site" "$pack" --state "$state" --minutes "$minutes"
fi
sets=()
[ $device = cuda ] && [ $phase = hyperbones ] && sets=("${GPU_PHASE2[@]}")
exec "${job[@]}" run --config "$config" --pack "$pack" --state "$state" --out "${OUT:-$FOLDER/out-$phase}" \
  --device $device --minutes "$minutes" $quick "${sets[@]}" ${TRAIN_ARGS:-}
