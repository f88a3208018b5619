#!/usr/bin/env bash
# One GPU training session (docs/training.md). Paste into the device tool as its command:
#
#   bash scripts/gpu_train.sh finetune 9
#   bash scripts/gpu_train.sh base 9 --count 256
#
# Arguments: STAGE (base | finetune), MINUTES (wall budget of the whole session; a device
# command may run 10 minutes at most), then any scripts/gpu_session.py option. Writes
# base.pt or slope.pt, log.jsonl, session.json, eval.png and console.log to $OUT (runs/gpu_out
# when $OUT is unset); copy the .pt into models/ before the next session so it continues.
set -euo pipefail
stage=${1:?usage: gpu_train.sh base|finetune MINUTES [gpu_session.py options]}
minutes=${2:-9}
shift $(( $# < 2 ? $# : 2 ))
out=${OUT:-runs/gpu_out}
mkdir -p "$out"
export PYTHONPATH=src PYTHONUNBUFFERED=1 TQDM_MININTERVAL=30
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || echo "no nvidia-smi"
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
python3 scripts/gpu_session.py --stage "$stage" --minutes "$minutes" --out "$out" "$@" 2>&1 | tee "$out/console.log"
