#!/bin/bash
# Physics PSNR (vkunroll unroll --mode physics --times gt) at the estimate's (c, fitted log offset) and at the
# same c with offset 0 (--contrast C: no fit, offset 0), per sequence. Usage: physics_offset_zero.sh SEQ...
set -euo pipefail
cli=${CLI:-build/vkunroll}; work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
for s in "$@"; do
  "$cli" unroll "$s" --out "$work/est" --mode physics --times gt --no-video --quiet 2>/dev/null
  c=$(/usr/bin/python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['physics']['contrast'])" "$work/est/summary.json")
  "$cli" unroll "$s" --out "$work/zero" --mode physics --times gt --no-video --quiet --contrast "$c" 2>/dev/null
  /usr/bin/python3 - "$s" "$work/est" "$work/zero" <<'PY'
import csv, json, sys
def mean(d):
    psnr = [float(r["psnr"]) for r in csv.DictReader(open(d + "/metrics.csv"))]
    return sum(psnr) / len(psnr)
p = json.load(open(sys.argv[2] + "/summary.json"))["physics"]
print(f"{sys.argv[1]}: c {p['contrast']:.3f}, fitted offset {p.get('log_offset', 0):g}: {mean(sys.argv[2]):.2f} dB; offset 0: {mean(sys.argv[3]):.2f} dB")
PY
  rm -rf "$work/est" "$work/zero"
done
