#!/bin/bash
# Device check (run on the GPU machine from the repo root, after tools/device/bundle.sh here): the
# Vulkan-facing GPU tests with the validation layer, then the kernel, event-tensor and model benches.
# Results go to $OUT (or ./device-out). See docs/gpu_nvidia.md.
#   bash .devrun/run.sh [tests|race|all]   tests: GPU tests + kernel/event/model benches (<= 9 min);
#                                          race: vkunroll against PyTorch CUDA, fp32 and fp16 (<= 9 min);
#                                          all: the essentials of both in one command (<= 7.5 min)
PHASE=${1:-tests}
# The device tool returns at most 8 files from $OUT: every raw output goes to one folder, packed into
# $OUT/device_outputs.tgz when the script ends (also on an error), beside the console log.
FINAL_OUT=${OUT:-$PWD/device-out}; mkdir -p "$FINAL_OUT"
OUT=/tmp/device_outputs; rm -rf "$OUT"; mkdir -p "$OUT"
trap 'tar czf "$FINAL_OUT/device_outputs.tgz" -C /tmp device_outputs' EXIT
R=$PWD
for f in .gl/*.deb; do dpkg -x $f /; done; ls -d /usr/local/nvidia/lib64 /usr/local/nvidia/lib 2>/dev/null > /etc/ld.so.conf.d/zz-nvidia.conf; ldconfig; ldconfig -p | grep -E "libGLX_nvidia|libvulkan" | head -3
nvidia-smi -L; nvidia-smi --query-gpu=name,driver_version,clocks.sm --format=csv
for j in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json; do [ -f $j ] && export VK_DRIVER_FILES=$j VK_ICD_FILENAMES=$j && break; done
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; echo "ICD: $VK_DRIVER_FILES"
mkdir -p /work; [ -e /work/main ] || ln -s "$R" /work/main
# the benches call /usr/bin/python3 for the NumPy / PyTorch peers; here the venv python holds numpy and torch
if ! /usr/bin/python3 -c 'import numpy' 2>/dev/null; then SP=$(/opt/torch/.venv/bin/python3 -c 'import site; print(site.getsitepackages()[0])'); RP=$(readlink -f /usr/bin/python3); rm -f /usr/bin/python3; printf '#!/bin/sh\nexport PYTHONPATH=%s\nexec %s "$@"\n' "$SP" "$RP" > /usr/bin/python3; chmod +x /usr/bin/python3; fi
/usr/bin/python3 -c 'import numpy, torch; print("numpy", numpy.__version__, "torch", torch.__version__)'
export LD_LIBRARY_PATH=$R/.devrun/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
export VK_LAYER_PATH=$R/.devrun/layers VKUNROLL_CACHE_DIR=/tmp/vkcache VKUNROLL_DEVICE=${VKUNROLL_DEVICE:-NVIDIA}
B=$R/.devrun/bin
VK_LOADER_DEBUG=error $B/vkunroll_gpu_tests --gtest_filter=Runtime.RoundTripEveryDtype > /tmp/probe.log 2>&1 || { head -40 /tmp/probe.log; exit 3; }; grep -i device /tmp/probe.log | head -3
# Every step runs under the phase's time budget (BUDGET_S seconds from here, default 450 for `all`,
# 540 otherwise): a step gets at most its own cap and what is left, and is skipped (said so) when
# fewer than 15 s remain, so one prepared command always ends inside a device call.
T0=$SECONDS
BUDGET=${BUDGET_S:-$([ "$PHASE" = all ] && echo 450 || echo 540)}
step() {  # step NAME CAP_S LOG CMD...
  local name=$1 cap=$2 log=$3; shift 3
  local left=$(( BUDGET - (SECONDS - T0) ))
  if [ $left -lt 15 ]; then echo "$name: skipped (out of the ${BUDGET} s budget)"; return 99; fi
  [ $cap -gt $left ] && cap=$left
  # line-buffered: a step stopped at its cap keeps what it printed (stdout to a file is block-buffered)
  timeout $cap stdbuf -oL -eL "$@" > "$log" 2>&1; local rc=$?
  echo "$name rc=$rc ($(( SECONDS - T0 )) s)"; return $rc
}
coopmat_tests() {
  # The cooperative-matrix conv first, on its own (issue 15): the real VK_NV_cooperative_matrix path has
  # only run emulated on lavapipe; its log says what the device offers and each case's error.
  VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 step "coopmat tests" 30 $OUT/gpu_tests_coopmat.log $B/vkunroll_gpu_tests --gtest_filter='Conv2dCoopmat.*'; CM_RC=$?
  grep -E '^\[ (device|measured) |^\[  (PASSED|FAILED|SKIPPED)|Failure|Skipped|error' $OUT/gpu_tests_coopmat.log | head -40
}
coopmat_bench() {  # where they passed: coopmat timed beside the fp16 paths it would replace
  [ "$CM_RC" = 0 ] || return 0
  step "coopmat bench" 45 $OUT/bench_kernels_coopmat.txt $B/vkunroll-bench-kernels --precision fp16 --no-naive --algos coopmat,gemm,winograd,blocked --reps 2 --torch-device cuda
  grep -E "coopmat|RDB|GFF" $OUT/bench_kernels_coopmat.txt | head -30
}
gpu_tests() {  # the full test binary leaves Conv2dCoopmat out (it ran first) and the direct convs' tests
  # (59 s for Conv2d.DirectMatchesReference alone on the H200, 2026-12-04: they run last, in direct_tests)
  VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 step "tests" ${1:-150} $OUT/gpu_tests.log $B/vkunroll_gpu_tests ${GTEST_ARGS:---gtest_filter=-Conv2dCoopmat.*:*.Direct*}
  grep -E '^\[  (PASSED|FAILED)|^\[  FAILED|tests ran|device' $OUT/gpu_tests.log | head -60; tail -2 $OUT/gpu_tests.log
}
direct_tests() {
  VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 step "direct tests" ${1:-120} $OUT/gpu_tests_direct.log $B/vkunroll_gpu_tests --gtest_filter='*.Direct*'
  grep -E '^\[  (PASSED|FAILED)|^\[       OK|tests ran' $OUT/gpu_tests_direct.log | head -20
}
race() {  # race MODE PRECISION SIZE [CHOICE=heuristic] [CAP_S=50]: the same network in PyTorch CUDA on the same card
  # CHOICE measured: the conv algorithms timed per shape on this GPU first (the table persists in
  # $VKUNROLL_CACHE_DIR across the runs); the bench also prints the heuristic's time beside it.
  # The first race also builds every pipeline (the driver compiles each) and PyTorch autotunes cuDNN
  # for each of its settings: on the H200 (2026-12-04) a 50 s cap was too short for that.
  local f=$OUT/race_${1}_${2}_${3}_${4:-heuristic}.txt
  step "race $1 $2 $3 ${4:-heuristic}" ${5:-50} $f $B/vkunroll-bench-model --mode $1 --size $3 --precision $2 --torch-device cuda --runs 5 --conv-choice ${4:-heuristic}
  grep -E "vulkan :|torch  :|ratio|conv choice|progress: (weights|run 1)" $f
}
per_layer() {
  step "per-layer" 60 $OUT/fp16_per_layer_small.txt $B/vkunroll-bench-model --mode m --size 346x260 --precision fp16 --per-layer --model $R/models/selfunroll_small_physics.safetensors
}
kernels() {  # every model conv shape in fp32 and fp16 against PyTorch's conv2d on the same card (cuDNN)
  step "kernels" ${1:-150} $OUT/bench_kernels_gpu.txt $B/vkunroll-bench-kernels --reps 3 --no-naive --precision fp32,fp16 --torch-device cuda --json $OUT/bench_kernels_gpu.json; tail -8 $OUT/bench_kernels_gpu.txt
}
case "$PHASE" in
tests)
  coopmat_tests; coopmat_bench; gpu_tests 150; direct_tests 120; kernels 150
  step dispatch 30 $OUT/bench_dispatch.txt $B/vkunroll-bench-dispatch; tail -3 $OUT/bench_dispatch.txt
  step layout 30 $OUT/bench_layout.txt $B/vkunroll-bench-layout; cat $OUT/bench_layout.txt
  step first-frame 40 $OUT/bench_first_frame.txt $B/vkunroll-bench-first-frame --model $R/models/selfunroll_small_physics.safetensors --rounds 3; cat $OUT/bench_first_frame.txt
  step events 100 $OUT/bench_event_tensor_h100.txt $B/vkunroll-bench-event-tensor; cat $OUT/bench_event_tensor_h100.txt
  step model 120 $OUT/bench_model_h100.txt $B/vkunroll-bench-model --torch-threads 16 --runs 3 --profile; head -30 $OUT/bench_model_h100.txt ;;
race)
  # S and M, fp32 and fp16, at the DAVIS346 size and at 640x480 (the paper's size); then fp16's
  # per-layer error on the shipped model. Each run prints ms per GS frame for both, the ratio, the
  # device share, the measured conv choice against the heuristic and the output diffs.
  race s fp32 640x480 heuristic 130
  for p in fp32 fp16; do for m in s m; do for sz in 346x260 640x480; do race $m $p $sz measured 60; done; done; done
  per_layer ;;
all)
  # ONE command for a single short slot, most important first: the never-run paths' tests, the
  # paper's goal (S fp32 at 640x480 against PyTorch), fp16 against PyTorch's fp16, the rest of the
  # tests, M, the per-layer report, the kernel bench with what time is left.
  # The S races take the measured conv choice, as `unroll` does on a GPU (auto); each also runs the
  # heuristic, interleaved, and prints both. The first race of a precision times every shape (about
  # 60-90 s at 640x480 on the H200, 2026-12-04). M's batch of 2 keys new table rows (n<=2), which
  # would need the same again: M and the smaller size take the heuristic here (phase race: measured).
  coopmat_tests; race s fp32 640x480 measured 200; race s fp16 640x480 measured 150; gpu_tests 100
  race m fp32 640x480 heuristic 60; race m fp16 640x480 heuristic 50; race s fp32 346x260 heuristic 40
  kernels 90; per_layer; coopmat_bench; direct_tests ;;
*) echo "usage: run.sh tests|race|all"; exit 2 ;;
esac
exit 0
