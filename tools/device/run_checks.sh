#!/bin/bash
# Device check (run on the GPU machine from the repo root, after tools/device/bundle.sh here): the
# Vulkan-facing GPU tests with the validation layer, then the kernel, event-tensor and model benches.
# Results go to $OUT (or ./device-out). See docs/gpu_nvidia.md.
#   bash .devrun/run.sh [tests|race]   tests: GPU tests + kernel/event/model benches (< 9 min);
#                                      race: vkunroll against PyTorch CUDA, fp32 and fp16 (< 7 min)
PHASE=${1:-tests}
OUT=${OUT:-$PWD/device-out}; mkdir -p "$OUT"
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
if [ "$PHASE" = tests ]; then
# The cooperative-matrix conv first, on its own (issue 15): the real VK_NV_cooperative_matrix path has
# only run emulated on lavapipe; its log says what the device offers and each case's error.
VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 timeout 45 $B/vkunroll_gpu_tests --gtest_filter='Conv2dCoopmat.*' > $OUT/gpu_tests_coopmat.log 2>&1; CM_RC=$?; echo "coopmat tests rc=$CM_RC"
grep -E '^\[ (device|measured) |^\[  (PASSED|FAILED|SKIPPED)|Failure|Skipped|error' $OUT/gpu_tests_coopmat.log | head -40
# where they passed: coopmat timed beside the fp16 paths it would replace, on the model's shapes (the
# full test run below leaves Conv2dCoopmat out: it ran here)
[ $CM_RC = 0 ] && { timeout 45 $B/vkunroll-bench-kernels --precision fp16 --no-naive --algos coopmat,gemm,winograd,blocked --reps 2 > $OUT/bench_kernels_coopmat.txt 2>&1; echo "coopmat bench rc=$?"; grep -E "coopmat|RDB|GFF" $OUT/bench_kernels_coopmat.txt | head -30; }
VKUNROLL_VALIDATION=1 VKUNROLL_VALIDATION_FATAL=1 timeout ${TEST_S:-150} $B/vkunroll_gpu_tests --gtest_brief=1 ${GTEST_ARGS:---gtest_filter=-Conv2dCoopmat.*} > $OUT/gpu_tests.log 2>&1; echo "tests rc=$?"
grep -E '^\[  (PASSED|FAILED)|^\[  FAILED|tests ran|device' $OUT/gpu_tests.log | head -60
timeout 150 $B/vkunroll-bench-kernels --reps 3 --json $OUT/bench_kernels_h100.json > $OUT/bench_kernels_h100.txt 2>&1; echo "kernels rc=$?"; tail -8 $OUT/bench_kernels_h100.txt
timeout 30 $B/vkunroll-bench-dispatch > $OUT/bench_dispatch.txt 2>&1; echo "dispatch rc=$?"; tail -3 $OUT/bench_dispatch.txt
timeout 100 $B/vkunroll-bench-event-tensor > $OUT/bench_event_tensor_h100.txt 2>&1; echo "events rc=$?"; cat $OUT/bench_event_tensor_h100.txt
timeout 120 $B/vkunroll-bench-model --torch-threads 16 --runs 3 --profile > $OUT/bench_model_h100.txt 2>&1; echo "model rc=$?"; head -30 $OUT/bench_model_h100.txt
exit 0
fi
# The race (issue 15): the same network in PyTorch CUDA on the same card, fp32 and fp16, S and M,
# at the DAVIS346 size and at 640x480 (the paper's size); then fp16's per-layer error on the shipped
# model. Each run prints ms per GS frame for both, the ratio, the device share and the output diffs.
for p in fp32 fp16; do for m in s m; do for sz in 346x260 640x480; do
  # --conv-choice measured: the conv algorithms timed per shape on this GPU first (the table persists
  # in $VKUNROLL_CACHE_DIR across the runs); the bench also prints the heuristic's time beside it.
  timeout 50 $B/vkunroll-bench-model --mode $m --size $sz --precision $p --torch-device cuda --runs 5 --conv-choice measured > $OUT/race_${m}_${p}_${sz}.txt 2>&1
  echo "race $m $p $sz rc=$?"; grep -E "vulkan :|torch  :|ratio|conv choice" $OUT/race_${m}_${p}_${sz}.txt
done; done; done
timeout 60 $B/vkunroll-bench-model --mode m --size 346x260 --precision fp16 --per-layer --model $R/.devrun/selfunroll_small.safetensors > $OUT/fp16_per_layer_small.txt 2>&1; echo "per-layer rc=$?"
