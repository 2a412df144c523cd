#!/bin/bash
# A/B timing of `vkunroll unroll` between two builds, alternating, in one run (ratios, never one
# side alone): tools/experiments/ab_unroll.sh OLD_BINARY NEW_BINARY SEQUENCE MODEL [REPS=3]
# Prints ms per GS frame (summary.json) and the traffic counters where the build has them.
set -euo pipefail
OLD=$1 NEW=$2 SEQ=$3 MODEL=$4 REPS=${5:-3}
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
for rep in $(seq 1 "$REPS"); do
  for side in before after; do
    B=$OLD; [ "$side" = after ] && B=$NEW
    "$B" unroll "$SEQ" --out "$OUT/$side" --model "$MODEL" --mode s --times 0.25,0.5,0.75 --sparse off --no-video --quiet \
      ${AB_EXTRA:-}
    /usr/bin/python3 -c "
import json; s=json.load(open('$OUT/$side/summary.json')); t=s.get('device_traffic_per_gs_frame',{})
print('$side', 'rep $rep', 'ms/GS frame total %.1f'%s['ms_per_gs_frame_total'],
      'down %s up %s submits %s'%(t.get('download_bytes'),t.get('upload_bytes'),t.get('submits')))"
    rm -rf "$OUT/$side"
  done
done
