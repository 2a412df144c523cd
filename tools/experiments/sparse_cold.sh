#!/bin/bash
# usage: tools/experiments/sparse_cold.sh SEQ [MODE] [ROUNDS]   sparse against dense as a user runs it: one cold
# `vkunroll unroll` per policy (off, fast --halo 0, exact --halo 0), alternating, every ground-truth
# instant of every frame. Prints per run the compute ms per GS frame (summary total less read, write,
# pipeline builds, the contrast estimate and setup, as docs/tiling.md counts it), the ratio to `off`
# of the same round, the PSNR and the work ratio. Each run pays for touching fresh memory once
# (docs/measurements.md), so a longer recording amortizes it; tools/experiments/sparse_rounds.py measures warm.
# Environment: CLI (default build/vkunroll), OUT (default /tmp/sparse_cold).
set -euo pipefail
cd "$(dirname "$0")/.."
seq=$1; mode=${2:-s}; rounds=${3:-2}
CLI=${CLI:-build/vkunroll}; OUT=${OUT:-/tmp/sparse_cold}
for r in $(seq 1 "$rounds"); do
  for policy in off "fast --halo 0" "exact --halo 0"; do
    out=$OUT/${policy%% *}
    # shellcheck disable=SC2086  # the policy's words are separate arguments
    "$CLI" unroll "$seq" --out "$out" --overwrite --mode "$mode" --times gt --no-video --quiet --sparse $policy
    /usr/bin/python3 - "$out/summary.json" "$policy" "$r" "$OUT/off_compute_ms" <<'PY'
import json, sys
from tools.experiments.sparse_rounds import compute_ms
path, policy, rnd, off_file = sys.argv[1:]
s = json.load(open(path))
c = compute_ms(s)
if policy == "off":
    open(off_file, "w").write(str(c))
off = float(open(off_file).read())
print(f"round {rnd}  {policy:15s} {s['targets']} targets  compute {c:7.1f} ms per GS frame  x{off / c:5.2f}  "
      f"PSNR {s['metrics']['mean_psnr']:.4f}  work {s.get('tiling', {}).get('work_ratio', 1.0):.3f}", flush=True)
PY
  done
done
