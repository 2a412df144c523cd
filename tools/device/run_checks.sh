#!/bin/bash
# The device check, run on the GPU machine from the repo root after tools/device/bundle.sh here
# (docs/gpu_nvidia.md, "The next GPU run"):
#   tar xJf .devrun.txz && bash .devrun/run.sh all        ONE command, at most 6 minutes (BUDGET_S=345)
# Phase `all`, in this order: the cooperative-matrix tests; the tuner (vkunroll-bench-tune, the
# published configuration, S and M, fp32 and fp16, 346x260 and 640x480, at most 55 s of timing); the race of
# S and M, fp32 and fp16, at 346x260 and 640x480 against PyTorch CUDA's best settings, each with a
# trace where the bench has --trace; then, with what is left, the shipped default model's table.
# Other phases: `tests` (every GPU test, the benches), `race` (the races alone).
# DRY_RUN=1 runs the same steps here with lavapipe standing in (tools/device/dry_run.sh): no driver
# set-up, PyTorch on the CPU, small sizes, so that a script error shows before the first GPU minute.
# Every raw output goes to one folder named by date and GPU, packed into $OUT/device_outputs.tgz when
# the script ends (also on an error); the device tool returns at most 8 files.
PHASE=${1:-all}
DRY=${DRY_RUN:-0}
R=$PWD
B=$R/.devrun/bin
FINAL_OUT=${OUT:-$PWD/device-out}; mkdir -p "$FINAL_OUT"
STAGE=/tmp/device_outputs; rm -rf "$STAGE"; mkdir -p "$STAGE"
trap 'tar czf "$FINAL_OUT/device_outputs.tgz" -C "$STAGE" . && echo "outputs: $FINAL_OUT/device_outputs.tgz ($(du -h "$FINAL_OUT/device_outputs.tgz" | cut -f1))"' EXIT
T0=$SECONDS

gpu_setup() {  # the loader and glvnd (carried .gl debs), the NVIDIA ICD, PyTorch for /usr/bin/python3
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ls -d /usr/local/nvidia/lib64 /usr/local/nvidia/lib 2>/dev/null > /etc/ld.so.conf.d/zz-nvidia.conf; ldconfig
  nvidia-smi -L; nvidia-smi --query-gpu=name,driver_version,clocks.sm --format=csv
  for j in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json; do
    [ -f $j ] && export VK_DRIVER_FILES=$j VK_ICD_FILENAMES=$j && break
  done
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  # the benches call /usr/bin/python3 for the PyTorch peer; there the venv's python holds torch
  if ! /usr/bin/python3 -c 'import numpy' 2>/dev/null; then
    SP=$(/opt/torch/.venv/bin/python3 -c 'import site; print(site.getsitepackages()[0])'); RP=$(readlink -f /usr/bin/python3)
    rm -f /usr/bin/python3; printf '#!/bin/sh\nexport PYTHONPATH=%s\nexec %s "$@"\n' "$SP" "$RP" > /usr/bin/python3; chmod +x /usr/bin/python3
  fi
  export VKUNROLL_DEVICE=${VKUNROLL_DEVICE:-NVIDIA} TORCH_DEVICE=cuda
  GPU=$(nvidia-smi --query-gpu=name --format=csv,noheader | head -1)
}

dry_setup() {  # lavapipe standing in for the GPU; PyTorch on the CPU; small sizes; caps x CAP_SCALE (a CPU is slower)
  export VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json VKUNROLL_DEVICE=${VKUNROLL_DEVICE:-llvmpipe} TORCH_DEVICE=cpu
  GPU="lavapipe dry run"
  RACE_SIZES=${RACE_SIZES:-64x48 96x64} TUNE_SIZES=${TUNE_SIZES:-64x48,96x64} RUNS=${RUNS:-1} CAP_SCALE=${CAP_SCALE:-6}
}

if [ "$DRY" = 1 ]; then dry_setup; else gpu_setup; fi
RACE_SIZES=${RACE_SIZES:-640x480 346x260} TUNE_SIZES=${TUNE_SIZES:-346x260,640x480} RUNS=${RUNS:-5} CAP_SCALE=${CAP_SCALE:-1}
echo "ICD: $VK_DRIVER_FILES"
# The benches find tools/bench_mirror.py under the source folder they were built in (bundle.sh records it).
SRC=$(cat .devrun/source_dir 2>/dev/null)
if [ -n "$SRC" ] && [ "$SRC" != "$R" ] && [ ! -e "$SRC" ]; then mkdir -p "$(dirname "$SRC")" && ln -s "$R" "$SRC"; fi
/usr/bin/python3 -c 'import numpy, torch; print("numpy", numpy.__version__, "torch", torch.__version__)'
export LD_LIBRARY_PATH=$R/.devrun/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
export VK_LAYER_PATH=$R/.devrun/layers VKUNROLL_CACHE_DIR=${VKUNROLL_CACHE_DIR:-/tmp/vkcache}
VK_LOADER_DEBUG=error $B/vkunroll_gpu_tests --gtest_filter=Runtime.RoundTripEveryDtype > /tmp/probe.log 2>&1 || { head -40 /tmp/probe.log; exit 3; }
grep -i device /tmp/probe.log | head -3
# One folder per date and GPU, as results keep them (tools/device/collect.sh unpacks it there).
RUN_DIR=$(date -u +%Y-%m-%d)-$(echo "$GPU" | tr 'A-Z ' 'a-z-' | tr -cd 'a-z0-9-')
O=$STAGE/$RUN_DIR; mkdir -p "$O"
{ echo "date_utc: $(date -u +%FT%TZ)"; echo "gpu: $GPU"; echo "phase: $PHASE"; echo "dry_run: $DRY"
  echo "bundle: $(cat .devrun/revision 2>/dev/null)"; } > "$O/run_info.txt"
exec > >(tee -a "$O/console.log") 2>&1

# Every step runs under the phase's time budget (BUDGET_S seconds from the start, default 345 for `all`,
# 540 otherwise): a step gets at most its own cap and what is left, and is skipped (said so) when fewer
# than 15 s remain, so that the one prepared command always ends inside a device call.
BUDGET=${BUDGET_S:-$(( CAP_SCALE * $([ "$PHASE" = all ] && echo 345 || echo 540) ))}
step() {  # step NAME CAP_S LOG CMD...
  local name=$1 cap=$(( $2 * CAP_SCALE )) log=$3; shift 3
  local left=$(( BUDGET - (SECONDS - T0) ))
  if [ $left -lt 15 ]; then echo "$name: skipped (out of the ${BUDGET} s budget)"; return 99; fi
  [ $cap -gt $left ] && cap=$left
  local s0=$SECONDS
  # line-buffered: a step stopped at its cap keeps what it printed (stdout to a file is block-buffered)
  timeout $cap stdbuf -oL -eL "$@" > "$log" 2>&1; local rc=$?
  echo "$name rc=$rc ($(( SECONDS - s0 )) s; $(( SECONDS - T0 )) s in all)"; return $rc
}
coopmat_tests() {  # the cooperative-matrix conv first, with the implicit-GEMM family and its folded convs (they share the gather); validation fatal
  VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 step "coopmat tests" ${1:-40} $O/gpu_tests_coopmat.log \
    $B/vkunroll_gpu_tests --gtest_filter='Conv2dCoopmat.*:Conv2dIgemm.*:Conv2dFold.*'; CM_RC=$?
  grep -E '^\[ (device|measured) |^\[  (PASSED|FAILED|SKIPPED)|Failure|Skipped|error' $O/gpu_tests_coopmat.log | head -20
}
tune() {  # tune NAME MODEL SIZES TILE CAP BUDGET: the conv table the races (and unroll) read
  step "tune $1" $5 $O/tune_$1.txt $B/vkunroll-bench-tune --model "$2" --size "$3" --tile $4 --precision all \
    --budget-s $6 --candidate-ms 8 --reps 10 --warm-ms 300
  grep -E "^(FMA|fp32|fp16|  budget|  [0-9]+ shapes were not|table|tune took)|heuristic / measured" $O/tune_$1.txt
}
race() {  # race MODE PRECISION SIZE CAP: the same network in PyTorch on the same card, best settings
  local name=race_${1}_${2}_${3} trace=()
  # the timeline trace of the race's runs, where this bench has --trace (the runtime's trace, issue 49)
  $B/vkunroll-bench-model --help 2>&1 | grep -q -- '--trace' && trace=(--trace $O/trace_${1}_${2}_${3}.json)
  step "race $1 $2 $3" $4 $O/$name.txt $B/vkunroll-bench-model --mode $1 --size $3 --precision $2 --torch-device $TORCH_DEVICE \
    --runs $RUNS --conv-choice cached "${trace[@]}"
  grep -E "vulkan :|torch  :|ratio|conv choice|progress: (weights|run 1)" $O/$name.txt
}
races() {  # the paper's size first, then the DAVIS346 size; fp32 before fp16, S before M
  local sz p m
  for sz in $RACE_SIZES; do for p in fp32 fp16; do for m in s m; do race $m $p $sz ${1:-45}; done; done; done
}
save_tables() {  # the measured tables, to commit for this GPU (models/conv_choices/, docs/tuning.md)
  mkdir -p $O/conv_tables; cp "$VKUNROLL_CACHE_DIR"/conv-choices-*.tsv $O/conv_tables/ 2>/dev/null; ls $O/conv_tables
}
MODEL=$R/models/selfunroll_small_physics.safetensors
case "$PHASE" in
all)
  coopmat_tests 40
  tune published published "$TUNE_SIZES" 0 75 55
  races 45
  tune default "$MODEL" "$TUNE_SIZES" 32 40 25
  save_tables ;;
race)
  tune published published "$TUNE_SIZES" 0 75 55; races 60; save_tables ;;
tests)
  coopmat_tests 40
  VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 step "tests" 200 $O/gpu_tests.log $B/vkunroll_gpu_tests --gtest_filter=-Conv2dCoopmat.*:*.Direct*
  grep -E '^\[  FAILED|tests ran' $O/gpu_tests.log | head -40
  VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 step "direct tests" 120 $O/gpu_tests_direct.log $B/vkunroll_gpu_tests --gtest_filter='*.Direct*'
  step kernels 150 $O/bench_kernels_gpu.txt $B/vkunroll-bench-kernels --reps 3 --no-naive --precision fp32,fp16 \
    --torch-device $TORCH_DEVICE --json $O/bench_kernels_gpu.json; tail -8 $O/bench_kernels_gpu.txt
  step per-layer 60 $O/fp16_per_layer_small.txt $B/vkunroll-bench-model --mode m --size 346x260 --precision fp16 --per-layer --model $MODEL ;;
*) echo "usage: run.sh all|race|tests"; exit 2 ;;
esac
echo "done in $(( SECONDS - T0 )) s; outputs in $RUN_DIR"
exit 0
