#!/usr/bin/env bash
# One chunk of the CPU training campaign of the shipped models (docs/training.md).
#
#   bash scripts/cpu_chunk.sh pilot HOURS      # the recipe's proof model on phi + c data -> models/pilot.pt
#   bash scripts/cpu_chunk.sh base HOURS       # friction-only base model  -> models/base.pt
#   bash scripts/cpu_chunk.sh finetune HOURS   # phi + c, from models/base.pt -> models/slope.pt
#
# The chunk (1) regenerates its dataset from the seed when data/ lacks it (deterministic and
# resumable, so a killed generation continues), (2) restores the run folder from the
# committed checkpoint in models/ when runs/ lacks it, (3) trains with --resume for at most
# HOURS of wall time (the last whole step is saved, exit 0), and (4) copies the checkpoint
# (weights + Adam state + step) and its log back to models/, ready to commit. The settings
# are the recipe chosen by the pilots in docs/training.md; change them there and here together.
set -euo pipefail
cd "$(dirname "$0")/.."
stage=${1:?usage: cpu_chunk.sh pilot|base|finetune HOURS}
hours=${2:?usage: cpu_chunk.sh pilot|base|finetune HOURS}
runout=${RUNOUT:-.venv/bin/runout}
threads=${THREADS:-2}

CELL=8          # m; 2 x 2 points per cell -> 4 m point spacing
FRAMES=480
NET=(--latent 64 --hidden 64 --message-passing-steps 5 --batch-size 2)
# The recipe (docs/training.md, "The recipe"): windows at rest (the default), noise in units of
# the data's velocity std; RECIPE_NOISE may override it for a pilot
RECIPE=(--noise "${RECIPE_NOISE:-0.1}")  # provisional: round 1 of the pilots; --exact-rest is being piloted
# bf16 autocast only where the CPU multiplies bfloat16 natively (AVX512-BF16 or AMX): on an
# AVX2-only CPU PyTorch falls back to a generic kernel, 14x slower than float32 (docs/training.md)
if grep -q -E 'avx512_bf16|amx_bf16' /proc/cpuinfo 2>/dev/null; then NET+=(--bf16); fi
case "$stage" in
  pilot)    data=data/ft8;   count=260; run=runs/pilot8; model=models/pilot.pt; stage_data=finetune
            schedule=(--lr 4e-4 --lr-decay-steps 200000); init=() ;;
  base)     data=data/base8; count=320; run=runs/base8; model=models/base.pt; stage_data=base
            schedule=(--lr 1e-4 --lr-decay-steps 300000); init=() ;;
  finetune) data=data/ft8;   count=260; run=runs/ft8;   model=models/slope.pt; stage_data=finetune
            schedule=(--lr 1e-4 --lr-decay-steps 300000); init=(--init models/base.pt) ;;
  *) echo "cpu_chunk.sh: the stage '$stage' is not one of pilot, base, finetune" >&2; exit 2 ;;
esac
log=${model%.pt}.log.jsonl

if [ ! -f "$data/metadata.json" ]; then
  OMP_NUM_THREADS=$threads "$runout" generate --stage "$stage_data" --count "$count" --cell-size "$CELL" \
    --frames "$FRAMES" --seed 0 --out "$data"
fi

resume=()
if [ -f "$run/checkpoint.pt" ]; then
  resume=(--resume)
elif [ -f "$model" ] && "${runout%/runout}/python" -c "import sys, torch; sys.exit('optimizer' not in torch.load(sys.argv[1], weights_only=True))" "$model"; then
  # a committed checkpoint of this campaign carries its optimiser state (an older weights-only
  # file, such as the smoke model, does not and is not continued)
  mkdir -p "$run"
  cp "$model" "$run/checkpoint.pt"
  [ -f "$log" ] && cp "$log" "$run/log.jsonl"
  resume=(--resume)
fi
if [ ${#resume[@]} -eq 1 ]; then init=(); fi

OMP_NUM_THREADS=$threads "$runout" train --data "$data" --out "$run" --steps 100000000 --max-hours "$hours" \
  "${NET[@]}" "${RECIPE[@]}" "${schedule[@]}" "${init[@]}" "${resume[@]}" \
  --save-every 1000 --log-every 100 --valid-every 5000 --valid-trajectories 4

cp "$run/checkpoint.pt" "$model.tmp" && mv "$model.tmp" "$model"
cp "$run/log.jsonl" "$log"
echo "chunk done: $model ($(du -h "$model" | cut -f1)) and $log; commit them with the figures in models/README.md"
