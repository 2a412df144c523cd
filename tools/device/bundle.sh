#!/bin/bash
# Bundles vkunroll's GPU tests and benches for a machine that has a GPU driver but none of the
# project's build dependencies (docs/gpu_nvidia.md): the Vulkan-facing tests (not the readers',
# which need OpenCV and HDF5) and the benches, relinked with --as-needed so that they need only
# libstdc++; the Khronos validation layer; the Vulkan loader's Debian package.
#   tools/device/bundle.sh [BUILD_DIR=build]   -> .devrun/ (bin, lib, layers, run.sh), packed as .devrun.txz, and .gl/
# The device tool carries at most 64 MiB with the working tree: unpacked the bundle is over 50 MiB (the
# validation layer alone 22), packed about 11. On the device: tar xJf .devrun.txz && bash .devrun/run.sh all
# tools/device/dry_run.sh builds it and runs that command here with lavapipe standing in.
set -euo pipefail
B=${1:-build}
R=$(cd "$(dirname "$0")/../.." && pwd)
cd "$R"
cmake --build "$B" --target vkunroll_tests vkunroll-bench-kernels vkunroll-bench-event-tensor vkunroll-bench-model vkunroll-bench-dispatch \
  vkunroll-bench-layout vkunroll-bench-first-frame vkunroll-bench-tune
rm -rf .devrun; mkdir -p .devrun/bin .devrun/layers .gl
LIBS=$(ninja -C "$B" -t commands bench/vkunroll-bench-kernels | tail -1 | grep -oE ' (lib[^ ]+\.a|/usr/lib[^ ]+\.(so[.0-9]*|a)|-l[a-z]+)' | tr '\n' ' ')
(cd "$B"
 for b in kernels event-tensor model dispatch layout first-frame tune; do
   c++ -O3 -Wl,--as-needed bench/CMakeFiles/vkunroll-bench-$b.dir/bench_*.cpp.o -o "$R/.devrun/bin/vkunroll-bench-$b" $LIBS
 done
 T=tests/CMakeFiles/vkunroll_tests.dir
 objs=""
 for t in backward_warp conv2d conv2d_coopmat conv_transpose2d copy_rect elementwise event_tensor model model_fp16 physics_unroll \
          precision reflection_pad runtime space_to_depth weights safetensors conv_choice backend_buffer op_test_harness conv2d_igemm conv2d_fold; do
   if [ -f $T/test_$t.cpp.o ]; then objs="$objs $T/test_$t.cpp.o"; fi  # conv2d_igemm: the GPU conv family (issue 49), where built
 done
 c++ -O3 -Wl,--as-needed $objs $T/vk_test_env.cpp.o $T/op_test_harness.cpp.o $T/shaders_kTestShaders/*.o -o "$R/.devrun/bin/vkunroll_gpu_tests" $LIBS \
     /usr/lib/x86_64-linux-gnu/libgtest.a -lpthread)
# Shared libraries the binaries still need beyond glibc and libstdc++ (the model layer's CPU backend
# runs on OpenCV's parallel_for_): copied beside them, found through LD_LIBRARY_PATH in run.sh.
mkdir -p .devrun/lib
for f in .devrun/bin/*; do
  ldd "$f" | awk '/=> \// {print $3}' | { grep -vE '/(libc|libm|libdl|libpthread|librt|libgcc_s|libstdc\+\+|ld-linux[^/]*|libvulkan)\.so' || true; } |
    while read -r l; do cp -Ln "$l" .devrun/lib/ 2>/dev/null || true; done
done
cp /usr/lib/x86_64-linux-gnu/libVkLayer_khronos_validation.so .devrun/layers/
sed 's|"library_path": *"[^"]*"|"library_path": "./libVkLayer_khronos_validation.so"|' \
    /usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json > .devrun/layers/VkLayer_khronos_validation.json
cp tools/device/run_checks.sh .devrun/run.sh
# The benches find tools/bench_mirror.py under the source folder they were built in: run.sh links it there.
echo "$R" > .devrun/source_dir
echo "$(git rev-parse --short HEAD)$(git diff --quiet HEAD || echo ' (with uncommitted changes)')" > .devrun/revision
# The loader (and glvnd, which NVIDIA's Vulkan ICD needs) as Debian packages, unpacked there.
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p /tmp/amd64/partial
apt-get $o update >/dev/null
(cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
tar cJf .devrun.txz .devrun
echo "bundle ready: .devrun.txz ($(du -h .devrun.txz | cut -f1)) and .gl/ (git-ignored); carry both, and run there from the repo root:"
echo "  tar xJf .devrun.txz && bash .devrun/run.sh all"
