#!/bin/bash
# The device command, dry-run here with lavapipe standing in, so that the first GPU minute is not
# spent on a script error (issue 49):
#   tools/device/dry_run.sh [BUILD_DIR=build] [PHASE=all]
# Builds the bundle (tools/device/bundle.sh), copies what the device tool would carry (the working
# tree's tracked and untracked-not-ignored files, .devrun.txz, .gl) into a fresh folder, checks that
# it fits the tool's 64 MiB, and runs there the command the GPU machine runs, with DRY_RUN=1
# (run_checks.sh: lavapipe, PyTorch on the CPU, small sizes). The outputs land in that folder's out/.
set -euo pipefail
B=${1:-build}
PHASE=${2:-all}
R=$(cd "$(dirname "$0")/../.." && pwd)
cd "$R"
t0=$SECONDS
bash tools/device/bundle.sh "$B"
D=$(mktemp -d /tmp/vkunroll-devrun-dry.XXXXXX)
git ls-files -co --exclude-standard -z | tar -cf - --null -T - | tar -xf - -C "$D"
cp -r .devrun.txz .gl "$D"/
mib=$(du -sm --apparent-size "$D" | cut -f1)
echo "what the device tool would carry: $mib MiB (limit 64) in $D; bundle built in $(( SECONDS - t0 )) s"
[ "$mib" -le 64 ] || { echo "dry run: over the device tool's 64 MiB"; exit 4; }
cd "$D"
s0=$SECONDS
# the device command as docs/gpu_nvidia.md gives it, with lavapipe standing in and a cache of its own
tar xJf .devrun.txz && DRY_RUN=1 OUT="$D/out" VKUNROLL_CACHE_DIR="$D/cache" bash .devrun/run.sh "$PHASE"
echo "dry run: the device command took $(( SECONDS - s0 )) s; outputs in $D/out"
tar tzf "$D/out/device_outputs.tgz"
