#!/usr/bin/env bash
# The README's two commands:
#   bash scripts/bootstrap.sh          install what is missing (apt), build Release, run the demo
#   bash scripts/bootstrap.sh test     same set-up, then run the whole test suite
# Everything comes from Debian 12's packages; nothing is downloaded at build or run time.
set -euo pipefail
mode="${1:-demo}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${VKUNROLL_BUILD_DIR:-$root/build}"

packages=(
  cmake ninja-build g++ pkg-config git
  libvulkan-dev libvulkan-volk-dev mesa-vulkan-drivers vulkan-validationlayers vulkan-tools
  glslang-tools spirv-tools
  libglm-dev libopencv-dev libhdf5-dev hdf5-filter-plugin-blosc-serial hdf5-tools
  liblz4-dev libzstd-dev libflatbuffers-dev flatbuffers-compiler libzip-dev zlib1g-dev nlohmann-json3-dev libcli11-dev
  libgtest-dev libgmock-dev
  python3-torch python3-numpy python3-h5py python3-matplotlib python3-pytest snakemake
  python3-dev pybind11-dev python3-pybind11
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
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
if [ -z "${VK_DRIVER_FILES:-}${VK_ICD_FILENAMES:-}" ] && ! ls /usr/share/vulkan/icd.d/ /etc/vulkan/icd.d/ 2>/dev/null | grep -qv lvp; then
  export VK_DRIVER_FILES="$lvp" VK_ICD_FILENAMES="$lvp"
fi

jobs="$(nproc)"
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$build" -j "$jobs"

case "$mode" in
  test)
    cd "$build"
    ctest --output-on-failure -j "$jobs" --timeout 900
    ;;
  demo)
    if "$build/vkunroll" --help | grep -q '^  demo'; then
      "$build/vkunroll" demo
    else
      "$build/vkunroll" devices
    fi
    ;;
  build) ;;
  *)
    echo "usage: bash scripts/bootstrap.sh [demo|test|build]" >&2
    exit 2
    ;;
esac
