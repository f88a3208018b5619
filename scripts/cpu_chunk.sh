#!/usr/bin/env bash
# One chunk of the CPU training campaign of the shipped models (docs/training.md).
#
#   bash scripts/cpu_chunk.sh pilot HOURS      # the recipe's proof model on phi + c data -> models/pilot.pt
#   bash scripts/cpu_chunk.sh base HOURS       # friction-only base model  -> models/base.pt
#   bash scripts/cpu_chunk.sh finetune HOURS   # phi + c, from models/base.pt -> models/slope-train.pt
#   BASE=models/base-best20000.pt ONSET=0:0.4:4,12000:0.5:2 bash scripts/cpu_chunk.sh finetune HOURS
#
# The chunk (1) regenerates its dataset from the seed when data/ lacks it (deterministic and
# resumable, so a killed generation continues), (2) restores the run folder from the
# committed checkpoint in models/ when runs/ lacks it, if that checkpoint was trained with the
# recipe (an older one, solver 3's, is never continued: the stage starts afresh), (3) trains with --resume for at most
# HOURS of wall time (the last whole step is saved, exit 0), and (4) copies the checkpoint
# (weights + Adam state + step) and its log back to models/, ready to commit. The fine-tune's
# resumable run is models/slope-train.pt; the shipped models/slope.pt is whichever file of the
# run (its last or its best.pt) does best on 16 held-out scenes from rest (docs/training.md). The settings
# are the recipe chosen by the pilots in docs/training.md (runout.train_settings.TrainConfig's
# defaults), passed explicitly (recipe_options) so that the chunk says what it trains with.
set -euo pipefail
cd "$(dirname "$0")/.."
stage=${1:?usage: cpu_chunk.sh pilot|base|finetune HOURS}
hours=${2:?usage: cpu_chunk.sh pilot|base|finetune HOURS}
runout=${RUNOUT:-.venv/bin/runout}
threads=${THREADS:-2}
base=${BASE:-models/base.pt}   # the fine-tune's start: BASE=models/base-best20000.pt takes a run's best.pt instead
onset=${ONSET:-}               # ONSET="0:0.4:4,12000:0.5:2" replaces the recipe's onset schedule (runout train --onset-schedule); a resumed run keeps its own

CELL=8          # m; 2 x 2 points per cell -> 4 m point spacing
FRAMES=480
NET=(--latent 64 --hidden 64 --message-passing-steps 5 --batch-size 2)
# The recipe (TrainConfig's defaults, runout.train_settings.RECIPE names them; chosen by the pilots
# in docs/training.md, rounds 8-10):
# learning rate and decay, noise 0.01 of the velocity std, no noise on the scene at rest,
# pushforward 2, a weight average, the onset of motion drawn in three phases, the overburden
# input, and half the windows mirrored left-right (--mirror 0.5, from fine-tune chunk 7)
read -r -a RECIPE <<< "$("${runout%/runout}/python" -c 'from runout.train_settings import recipe_options; print(" ".join(recipe_options()))')"
# bf16 autocast only where the CPU multiplies bfloat16 natively (AVX512-BF16 or AMX): on an
# AVX2-only CPU PyTorch falls back to a generic kernel, 14x slower than float32 (docs/training.md)
if grep -q -E 'avx512_bf16|amx_bf16' /proc/cpuinfo 2>/dev/null; then NET+=(--bf16); fi
case "$stage" in
  pilot)    data=data/ft8;   count=260; run=runs/pilot8; model=models/pilot.pt; stage_data=finetune
            init=() ;;
  base)     data=data/base8; count=320; run=runs/base8; model=models/base.pt; stage_data=base
            init=() ;;
  finetune) data=data/ft8;   count=260; run=runs/ft8;   model=models/slope-train.pt; stage_data=finetune
            init=(--init "$base") ;;
  *) echo "cpu_chunk.sh: the stage '$stage' is not one of pilot, base, finetune" >&2; exit 2 ;;
esac
log=${model%.pt}.log.jsonl

if [ ! -f "$data/metadata.json" ]; then
  OMP_NUM_THREADS=$threads "$runout" generate --stage "$stage_data" --count "$count" --cell-size "$CELL" \
    --frames "$FRAMES" --seed 0 --out "$data"
fi

# Whether a checkpoint was trained with this recipe on solver-6 data: the recipe's settings
# (--exact-rest among them) entered the checkpoints with it; the models committed before it
# (solver 3, weights and Adam state) must not be continued, and a fine-tune must not start from them
# Each check exits 0 (yes) or 10 (no); a file python cannot read (a damaged file, a missing torch)
# stops the chunk with one sentence instead of reading as "predates the recipe"
recipe_check() {  # $1: weights (a fine-tune's start needs the weights and the recipe's settings) or checkpoint (also Adam's state); $2: the file
  local rc=0
  "${runout%/runout}/python" -c "
import sys
try:
    import torch
    from runout.train_settings import trained_with_recipe
    c = torch.load(sys.argv[2], weights_only=True, map_location='cpu')
except Exception as e:
    print(f'cpu_chunk.sh: could not read {sys.argv[2]} as a checkpoint ({type(e).__name__}: {(str(e).splitlines() or [\"\"])[0]})', file=sys.stderr)
    sys.exit(3)
ok = trained_with_recipe(c.get('train', {})) and (sys.argv[1] == 'weights' or 'optimizer' in c)
sys.exit(0 if ok else 10)" "$1" "$2" || rc=$?
  case $rc in
    0) return 0 ;;
    10) return 1 ;;
    3) exit 2 ;;
    *) echo "cpu_chunk.sh: could not read $2 (python exited with $rc)" >&2; exit 2 ;;
  esac
}
recipe_weights() { recipe_check weights "$1"; }
recipe_checkpoint() { recipe_check checkpoint "$1"; }
resume=()
if [ -f "$run/checkpoint.pt" ] && recipe_checkpoint "$run/checkpoint.pt"; then
  resume=(--resume)
elif [ -f "$run/checkpoint.pt" ]; then
  echo "cpu_chunk.sh: $run/checkpoint.pt predates the recipe; move $run away to start the stage afresh" >&2
  exit 2
elif [ -f "$model" ] && recipe_checkpoint "$model"; then
  mkdir -p "$run"
  cp "$model" "$run/checkpoint.pt"
  [ -f "$log" ] && cp "$log" "$run/log.jsonl"
  resume=(--resume)
elif [ -f "$model" ]; then
  echo "cpu_chunk.sh: $model predates the recipe (solver 3 or an older recipe), so this chunk starts the stage afresh in $run and replaces it at the end (git keeps the old file)" >&2
fi
if [ "$stage" = finetune ] && [ ${#resume[@]} -eq 0 ] && ! recipe_weights "$base"; then
  echo "cpu_chunk.sh: $base predates the recipe; train the base stage first (bash scripts/cpu_chunk.sh base HOURS)" >&2
  exit 2
fi
if [ ${#resume[@]} -eq 1 ]; then init=(); fi
# A resumed run keeps the onset schedule it was started with (ONSET= included) unless ONSET= is given again
if [ -z "$onset" ] && [ ${#resume[@]} -eq 1 ]; then
  onset=$("${runout%/runout}/python" -c "import sys, torch; c = torch.load(sys.argv[1], weights_only=True, map_location='cpu'); print(','.join(f'{a}:{b:g}:{f}' for a, b, f in c['train'].get('onset_schedule', ())))" "$run/checkpoint.pt")
fi
if [ -n "$onset" ]; then
  for i in "${!RECIPE[@]}"; do if [ "${RECIPE[$i]}" = --onset-schedule ]; then RECIPE[i+1]=$onset; fi; done
  echo "cpu_chunk.sh: onset schedule $onset" >&2
fi

OMP_NUM_THREADS=$threads "$runout" train --data "$data" --out "$run" --steps 100000000 --max-hours "$hours" \
  "${NET[@]}" "${RECIPE[@]}" "${init[@]}" "${resume[@]}" \
  --save-every 500 --log-every 50 --valid-every 5000 --valid-trajectories 4

cp "$run/checkpoint.pt" "$model.tmp" && mv "$model.tmp" "$model"
cp "$run/log.jsonl" "$log"
echo "chunk done: $model ($(du -h "$model" | cut -f1)) and $log; commit them with the figures in docs/training.md (the campaign journal)"
