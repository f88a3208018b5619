#!/usr/bin/env bash
# The measurement that ends a learned engine's campaign (issue 25 item 3, issue 57 item 5):
# every study of the paper's sections 5 and 6 with one model of either engine (a GNS or a neural
# MPM: the file says which, and every label names it), rolled out from rest against solver 6 at
# the model's resolution, then docs/results.md written from the outputs.
#
#   bash scripts/final_evaluation.sh models/slope.pt runs/final            # columns, slope, diagnostics, inverse
#   bash scripts/final_evaluation.sh models/neural-mpm.pt runs/final-nmpm  # the same studies of the neural MPM
#   STUDIES="inverse" bash scripts/final_evaluation.sh models/slope.pt runs/final
#   SENSITIVITY=1 bash scripts/final_evaluation.sh models/slope.pt runs/final   # also the data-size study
#   EXTRA="--scale 0.2 --frames 12" DOC=/tmp/r.md bash scripts/final_evaluation.sh models/slope.pt /tmp/f  # a wiring check
#
# Each study resumes or reuses what is already in OUT and in the MPM cache (the MPM runs once
# per scene; a killed inverse continues from its history), so the script can be run again
# after a crash or in the next session. Settings are the paper's: the 75-case column grid
# (a = 0.5, 1, 2; phi 0-45 degrees; c 10-70 kPa) over 600 frames, the four-layer slope over its
# 480 frames with both engines timed on this machine, the diagnostics at the paper's worst
# column, the dam inverse (examples/dam_inverse.toml) through the model and through the MPM-AD
# yardstick. The data-size study (paper section 6, GNS only) fine-tunes subsets of data/ft8 from
# the GNS base model, as the paper does (SENSITIVITY_INIT, default models/base-best20000.pt, the campaign's own
# start; SIZES, default 10,50,130,250; STEPS fine-tuning steps each, default 3000; one epoch as
# the second budget) with the recipe that trained the shipped model, and is off unless
# SENSITIVITY=1: on the 2-core CPU (about 3.4 steps/s) 3,000 steps take about 15 min a subset,
# one epoch of 250 scenes is about 60,000 steps (5 h), and the campaign's own 130,000 steps a
# subset would be about 42 h for four sizes; BUDGETS=steps runs the fixed-step budget alone. Each study's wall time goes to
# OUT/timings.txt; the report goes to DOC (default docs/results.md).
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:?usage: final_evaluation.sh MODEL OUT}
out=${2:?usage: final_evaluation.sh MODEL OUT}
runout=${RUNOUT:-.venv/bin/runout}
studies=${STUDIES:-columns slope diagnostics inverse}
doc=${DOC:-docs/results.md}
read -r -a extra <<< "${EXTRA:-}"   # options added to every MPM-backed study (a quick look: not the paper's settings)
[ -f "$model" ] || { echo "final_evaluation.sh: $model: no such model file." >&2; exit 2; }
sinit=${SENSITIVITY_INIT:-models/base-best20000.pt}   # the base every subset of the data-size study is fine-tuned from
if [ "${SENSITIVITY:-0}" = 1 ] && [ ! -f "$sinit" ]; then
  echo "final_evaluation.sh: SENSITIVITY_INIT=$sinit: no such model file (the base every subset is fine-tuned from)." >&2; exit 2
fi
mkdir -p "$out"

timed() {  # $1: study; the rest: its command
  local name=$1 t0 t1
  shift
  t0=$(date +%s)
  echo "== $name: $*"
  "$@"
  t1=$(date +%s)
  echo "$name $((t1 - t0)) s  $(date -u +%FT%TZ)  $(nproc --all) cores, OMP_NUM_THREADS=${OMP_NUM_THREADS:-unset}, load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out/timings.txt"
}

for study in $studies; do
  case "$study" in
    columns)     timed columns "$runout" evaluate columns --model "$model" --out "$out" --frames 600 --no-progress "${extra[@]}" ;;
    slope)       timed slope "$runout" evaluate slope --model "$model" --out "$out" --rerun-mpm --no-progress "${extra[@]}" ;;
    diagnostics) timed diagnostics "$runout" evaluate diagnostics --model "$model" --out "$out" --no-progress "${extra[@]}" ;;
    inverse)     timed inverse "$runout" evaluate inverse --model "$model" --out "$out" --no-progress "${extra[@]}" ;;
    *) echo "final_evaluation.sh: the study '$study' is not one of columns, slope, diagnostics, inverse" >&2; exit 2 ;;
  esac
done
if [ "${SENSITIVITY:-0}" = 1 ]; then
  timed sensitivity "$runout" evaluate sensitivity --data data/ft8 --init "$sinit" --out "$out" --split valid \
    --sizes "${SIZES:-10,50,130,250}" --steps "${STEPS:-3000}" --epochs 1 --budgets "${BUDGETS:-steps,epochs}" \
    --held-out 16 --no-progress
fi
"$runout" evaluate report --out "$out" --doc "$doc"
echo "wrote $doc; timings in $out/timings.txt"
