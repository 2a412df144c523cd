#!/bin/bash
# A fault and bad-input campaign against the built CLI: each case's exit code and first stderr line,
# as a Markdown table (docs/campaigns.md quotes its counts). Writes only under a temporary folder.
#   VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json bash tools/checks/cli_campaign.sh build/vkunroll
set -u
V=$(realpath "${1:-build/vkunroll}")
T=$(mktemp -d /tmp/vkunroll-campaign.XXXXXX)
trap 'rm -rf "$T"' EXIT
export VKUNROLL_CACHE_DIR=$T/cache
"$V" simulate --out "$T/seq" --preset clean --size 64x48 --frames 3 --gt-per-frame 2 --quiet || exit 1
"$V" simulate --out "$T/seqtxt" --preset clean --size 64x48 --frames 3 --events-format txt --quiet || exit 1
S=$T/seq
: > "$T/empty.txt"
printf '# t x y p\n12000 3 4 1\n12001 64 4 0\n' > "$T/bad.txt"
printf 'not an event file\n\x00\x01' > "$T/garbage.txt"
cp -r "$S" "$T/nometa"; rm "$T/nometa/meta.json"
cp -r "$S" "$T/badpng"; echo x > "$T/badpng/rs/000001.png"
cp -r "$S" "$T/badmeta"; echo '{"frames": [' > "$T/badmeta/meta.json"
touch "$T/afile"; mkfifo "$T/fifo"
n=0
echo "| # | case | exit | first line of stderr |"
echo "|---|---|---|---|"
run() {  # run NAME COMMAND (through bash -c, for ulimit and environment prefixes); runs it once
  local name=$1; shift
  n=$((n + 1))
  bash -c "$*" >/dev/null 2>"$T/err"
  local rc=$?
  local out; out=$(grep -v '^vkunroll: device\|^unroll: [0-9]\|^unroll: physics\|^usage:\|^(see' "$T/err" | head -1)
  out=${out//$T/\$T}
  out=$(sed -E "s/\.tmp[0-9]+/.tmpPID/g" <<< "$out")
  echo "| $n | $name | $rc | ${out//|/\\|} |"
}
U="$V unroll $S --quiet --no-video"
X="$V voxelize $S --frames 0 --times 0.5"
run "voxelize --bins 0" "$X --bins 0 --out $T/v1"
run "voxelize --bins 0 --cpu" "$X --bins 0 --cpu --out $T/v2"
run "voxelize --target-exposure -5" "$X --target-exposure -5 --out $T/v3"
run "voxelize --crop 0,0,0,0" "$X --crop 0,0,0,0 --out $T/v4"
run "voxelize --crop beyond the sensor" "$X --crop 60,40,10,10 --out $T/v5"
run "voxelize --out a FIFO" "$X --out $T/fifo"
run "voxelize --out in a missing folder" "$X --out $T/nodir/v.st"
run "voxelize under ulimit -f 1" "ulimit -f 1; $X --out $T/v6"
run "unroll under ulimit -f 2 (frame PNG)" "ulimit -f 2; $U --out $T/o1"
run "unroll under ulimit -f 100 (contact sheet)" "ulimit -f 100; $V unroll $S --quiet --out $T/o2"
run "unroll --out an existing file" "$U --out $T/afile"
run "unroll --out /" "$U --out /"
run "unroll into an existing output" "$U --out $T/o3 && $U --out $T/o3"
run "unroll --overwrite a non-vkunroll folder" "mkdir -p $T/mine && touch $T/mine/x && $U --out $T/mine --overwrite"
run "unroll --overwrite and --resume" "$U --out $T/o4 --overwrite --resume"
run "unroll --resume into a fresh folder" "$U --out $T/o5 --resume"
run "empty event file" "$U --out $T/o6 --events $T/empty.txt --contrast 0.2"
run "garbage event file" "$U --out $T/o7 --events $T/garbage.txt --contrast 0.2"
run "out-of-sensor events (--on-bad error)" "$U --out $T/o8 --events $T/bad.txt --contrast 0.2"
run "out-of-sensor events (--on-bad drop)" "$U --out $T/o9 --events $T/bad.txt --contrast 0.2 --on-bad drop"
run "--events a folder" "$U --out $T/o10 --events $T"
run "--events missing" "$U --out $T/o11 --events $T/none.txt"
run "meta.json deleted (events.h5)" "$V unroll $T/nometa --quiet --out $T/o12"
run "meta.json truncated" "$V unroll $T/badmeta --quiet --out $T/o13"
run "an RS frame not a PNG" "$V unroll $T/badpng --quiet --out $T/o14"
run "missing sequence" "$V unroll $T/none --quiet --out $T/o15"
run "missing SEQUENCE argument" "$V unroll --out $T/o16"
run "unknown command" "$V frobnicate"
run "unknown option" "$U --out $T/o17 --frobnicate"
run "--model a folder" "$U --out $T/o18 --model $T"
run "--model missing" "$U --out $T/o19 --model $T/none.safetensors"
run "--model not safetensors" "$U --out $T/o20 --model $T/bad.txt"
run "--mode m without --model" "$U --out $T/o21 --mode m"
run "--contrast inf" "$U --out $T/o22 --contrast inf"
run "--contrast nan" "$U --out $T/o23 --contrast nan"
run "--times inf" "$U --out $T/o24 --times inf"
run "--times empty" "$U --out $T/o25 --times ''"
run "--times-us far outside" "$U --out $T/o26 --times-us 9000000000"
run "--t0s-us near the int64 limit" "$U --out $T/o27 --t0s-us 9223372036854775000,9223372036854775100,9223372036854775200"
run "--t0s-us swapped" "$U --out $T/o28 --t0s-us 110000,60000,17700"
run "--t0s-us wrong count" "$U --out $T/o29 --t0s-us 1,2"
run "--line-delay-us -1" "$U --out $T/o30 --line-delay-us -1"
run "--exposure-us 0" "$U --out $T/o31 --exposure-us 0"
run "--frames 99" "$U --out $T/o32 --frames 99"
run "--frames 2:1" "$U --out $T/o33 --frames 2:1"
run "--tile 33" "$U --out $T/o34 --tile 33"
run "--fps 0" "$U --out $T/o35 --fps 0"
run "--threads -1" "$U --out $T/o36 --threads -1"
run "--precision fp16 --backend cpu" "$U --out $T/o37 --precision fp16 --backend cpu"
run "--device 7" "$U --out $T/o38 --device 7"
run "--device uuid:ffff" "$U --out $T/o39 --device uuid:ffff"
run "--device uuid:zz" "$U --out $T/o40 --device uuid:zz"
run "VKUNROLL_DEVICE=nosuch" "VKUNROLL_DEVICE=nosuch $U --out $T/o41"
run "no Vulkan driver" "VK_DRIVER_FILES=$T/none.json VK_ICD_FILENAMES=$T/none.json $U --out $T/o42"
run "simulate --size 0x48" "$V simulate --out $T/s1 --size 0x48"
run "simulate --frames 0" "$V simulate --out $T/s2 --frames 0"
run "events on a missing file" "$V events $T/none.txt"
run "events on garbage" "$V events $T/garbage.txt"
run "events on an empty file" "$V events $T/empty.txt"
run "infer --out a FIFO" "$V infer --model $T/none --inputs $T/none --out $T/fifo"
