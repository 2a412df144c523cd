#!/bin/bash
# usage: tools/adapt_heldout.sh MODEL NAME SEQ...   adaptation of MODEL to each held-out SEQ: 4 + 4 minutes,
# lr 1e-4 constant, crops 96x96, batch 2 (fixed before looking at any result), then scoring.
cd /work/wt-model
model=$1; name=$2; shift 2
for s in "$@"; do
  out=runs/adapt_${name}_$s
  mkdir -p $out
  common="--adapt data/natural/heldout/$s --from $model --minutes 8 --crop 96x96 --batch 2 --lr 1e-4 --constant-lr --threads 1 --print-every 30 --ckpt-every 10 --seed 1"
  nice -n 10 /usr/bin/python3 tools/train.py $common --out $out --chunk-minutes 4 > $out/adapt.log 2>&1
  nice -n 10 /usr/bin/python3 tools/train.py --export-checkpoint $out/checkpoint.pt $out/adapted_4min.safetensors >> $out/adapt.log 2>&1
  nice -n 10 /usr/bin/python3 tools/train.py $common --out $out --resume $out/checkpoint.pt >> $out/adapt.log 2>&1
  nice -n 10 /usr/bin/python3 tools/natural_eval.py --data data/natural/heldout/$s --cli build/vkunroll --threads 1 \
     --model base=$model --model adapt4=$out/adapted_4min.safetensors --model adapt8=$out/adapted.safetensors \
     --json $out/eval.json > $out/eval.log 2>&1
done
