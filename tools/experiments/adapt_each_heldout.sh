#!/bin/bash
# usage: tools/experiments/adapt_each_heldout.sh MODEL NAME SEQ...   adaptation of MODEL to each held-out SEQ: 4 + 4 minutes,
# lr 1e-4 constant, crops 96x96, batch 2 (fixed before looking at any result), then scoring.
# Environment: HELDOUT (default data/natural/heldout), RUNS (default runs), CLI (default build/vkunroll),
# MINUTES (default 8: the guard's choice exported at half of it, then resumed to the end), LR (default 1e-4),
# ADAPT_ARGS (more train.py options for both halves, e.g. "--adapt-anchor 1").
set -euo pipefail
cd "$(dirname "$0")/.."
HELDOUT=${HELDOUT:-data/natural/heldout}; RUNS=${RUNS:-runs}; CLI=${CLI:-build/vkunroll}; MINUTES=${MINUTES:-8}; LR=${LR:-1e-4}
half=$(( MINUTES / 2 ))
model=$1; name=$2; shift 2
for s in "$@"; do
  out=$RUNS/adapt_${name}_$s
  mkdir -p "$out"
  common="--adapt $HELDOUT/$s --from $model --minutes $MINUTES --crop 96x96 --batch 2 --lr $LR --constant-lr --threads 1 --print-every 30 --ckpt-every 10 --seed 1 ${ADAPT_ARGS:-}"
  nice -n 10 /usr/bin/python3 -m tools.train.train $common --out "$out" --chunk-minutes $half > "$out/adapt.log" 2>&1
  nice -n 10 /usr/bin/python3 -m tools.train.train --export-checkpoint "$out/checkpoint.pt" "$out/adapted_${half}min.safetensors" >> "$out/adapt.log" 2>&1
  nice -n 10 /usr/bin/python3 -m tools.train.train $common --out "$out" --resume "$out/checkpoint.pt" >> "$out/adapt.log" 2>&1
  nice -n 10 /usr/bin/python3 -m tools.eval.natural_eval --data "$HELDOUT/$s" --cli "$CLI" --threads 1 \
     --model base="$model" --model adapt${half}="$out/adapted_${half}min.safetensors" --model adapt${MINUTES}="$out/adapted.safetensors" \
     --json "$out/eval.json" > "$out/eval.log" 2>&1
done
