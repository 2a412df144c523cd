#!/bin/bash
# After a device call: unpacks device_outputs.tgz (the folder the device tool's files_at names) into
# the project's results, one folder per date and GPU (run_checks.sh names it), and lists what to commit.
#   tools/device/collect.sh FILES_AT [DEST_ROOT]
# DEST_ROOT: results/device where results/ exists, else docs/device (where earlier runs lie).
set -euo pipefail
SRC=${1:?usage: tools/device/collect.sh FILES_AT [DEST_ROOT]}
R=$(cd "$(dirname "$0")/../.." && pwd)
DEST=${2:-$([ -d "$R/results" ] && echo "$R/results/device" || echo "$R/docs/device")}
TGZ=$(find "$SRC" -name device_outputs.tgz | head -1)
[ -n "$TGZ" ] || { echo "collect: no device_outputs.tgz under $SRC"; exit 2; }
T=$(mktemp -d); tar xzf "$TGZ" -C "$T"
mkdir -p "$DEST"
for d in "$T"/*/; do
  name=$(basename "$d"); target=$DEST/$name; n=2
  while [ -e "$target" ]; do target=$DEST/$name-run$n; n=$((n + 1)); done  # a second call the same day keeps the first
  mv "$d" "$target"
  echo "collect: $target"; ls "$target"
  ls "$target"/conv_tables/*.tsv 2>/dev/null | sed 's|^|  a table to commit to models/conv_choices/ (docs/tuning.md): |'
done
rm -rf "$T"
