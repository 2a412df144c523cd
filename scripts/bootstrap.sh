#!/usr/bin/env bash
# The README's two commands:
#   bash scripts/bootstrap.sh          install what is missing (apt), build Release, run the demo
#   bash scripts/bootstrap.sh test     the same, plus what the suite needs, then run the whole suite
# Other modes: build (the demo's set-up without running it), workflow (adds Snakemake for
# workflow/Snakefile). Everything comes from Debian 12's packages; nothing is downloaded at build
# or run time.
set -euo pipefail
mode="${1:-demo}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${VKUNROLL_BUILD_DIR:-$root/build}"

# The library, the CLI, the Python module and the demo. OpenCV comes as its four modules: the
# whole libopencv-dev would add about 400 MB (VTK, dnn, viz) that vkunroll never links.
core_packages=(
  cmake ninja-build g++ pkg-config git
  libvulkan-dev libvulkan-volk-dev mesa-vulkan-drivers glslang-tools spirv-tools
  libglm-dev libopencv-core-dev libopencv-imgproc-dev libopencv-imgcodecs-dev libopencv-videoio-dev
  libhdf5-dev hdf5-filter-plugin-blosc-serial liblz4-dev libzstd-dev libflatbuffers-dev libzip-dev zlib1g-dev libbz2-dev
  nlohmann-json3-dev libcli11-dev
  python3-dev pybind11-dev python3-numpy
)
# The suite: validation layer, GoogleTest, Debian's PyTorch for the mirror and trainer tests, SciPy for the
# second event generator (tools/data/second_generator.py),
# Debian's rosbag for the tests that write ROS bags, and python3-build and python3-venv for the test
# that builds the wheel of `pip install .` and installs it into a fresh venv (tests/python/test_wheel.py).
# chromium-common (31 MB download) for its SwiftShader Vulkan driver (the `swiftshader` label) and its
# current Khronos validation layer (synchronization and GPU-assisted validation; docs/testing.md).
test_packages=(vulkan-validationlayers libgtest-dev libgmock-dev python3-pytest python3-torch python3-h5py python3-pil python3-scipy
  python3-rosbag python3-roslz4 python3-build python3-venv chromium-common)
# workflow/Snakefile (about 650 MB with its dependencies: cloud storage clients and more).
workflow_packages=(snakemake)
# The Slurm test (tests/python/test_slurm_workflow.py) starts its own munged, slurmctld and slurmd
# (8 packages, 13 MB installed); it configures nothing outside its temporary folder.
slurm_packages=(slurm-wlm munge)

case "$mode" in
  demo | build) packages=("${core_packages[@]}") ;;
  test) packages=("${core_packages[@]}" "${test_packages[@]}" "${workflow_packages[@]}" "${slurm_packages[@]}") ;;
  workflow) packages=("${core_packages[@]}" "${workflow_packages[@]}") ;;
  *)
    echo "usage: bash scripts/bootstrap.sh [demo|test|build|workflow]" >&2
    exit 2
    ;;
esac

installed() {  # no `| grep -q` under pipefail: grep's early exit can fail the pipeline (SIGPIPE)
  [[ "$(dpkg-query -W -f='${Status}' "$1" 2>/dev/null || true)" == "install ok installed" ]]
}
missing=()
for p in "${packages[@]}"; do
  installed "$p" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "vkunroll: installing ${#missing[@]} missing Debian packages: ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# Lavapipe is the fallback device everywhere; the loader still sees every other installed driver.
lvp=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
other_driver=0
for f in /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json; do
  [[ -e "$f" && "$f" != *lvp* ]] && other_driver=1
done
if [ -z "${VK_DRIVER_FILES:-}${VK_ICD_FILENAMES:-}" ] && ((other_driver == 0)); then
  export VK_DRIVER_FILES="$lvp" VK_ICD_FILENAMES="$lvp"
fi

jobs="$(nproc)"
# The demo needs neither the tests nor the benches; a build folder configured with them keeps them.
config=()
case "$mode" in
  test) config=(-DVKUNROLL_BUILD_TESTS=ON -DVKUNROLL_BUILD_BENCH=ON) ;;
  *) [ -f "$build/CMakeCache.txt" ] || config=(-DVKUNROLL_BUILD_TESTS=OFF -DVKUNROLL_BUILD_BENCH=OFF) ;;
esac
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release "${config[@]}"

case "$mode" in
  test)
    cmake --build "$build" -j "$jobs"
    cd "$build"
    ctest --output-on-failure -j "$jobs" --timeout 900
    ;;
  demo | build | workflow)
    targets=(vkunroll_cli)
    grep -qs '^VKUNROLL_BUILD_PYTHON:BOOL=ON' "$build/CMakeCache.txt" && targets+=(vkunroll_python)
    cmake --build "$build" -j "$jobs" --target "${targets[@]}"
    case "$mode" in
      demo) exec "$build/vkunroll" demo ;;
      workflow) echo "vkunroll: built; run a dataset with: snakemake -s workflow/Snakefile --cores $jobs --config sequences=DIR out=DIR vkunroll=$build/vkunroll" ;;
    esac
    ;;
esac
