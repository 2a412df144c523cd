#!/bin/bash
# Prints "uuid:<UUID>" of the GPU the scheduler gave this job, for `vkunroll --device`. Vulkan
# ignores CUDA_VISIBLE_DEVICES, so the GPU is named by its UUID, which NVIDIA's Vulkan driver
# reports as VkPhysicalDeviceIDProperties::deviceUUID (the UUID nvidia-smi shows after "GPU-").
# CUDA_VISIBLE_DEVICES (or SLURM_JOB_GPUS) may hold an index or a UUID; the first one is used.
set -euo pipefail
first=${CUDA_VISIBLE_DEVICES:-${SLURM_JOB_GPUS:-}}
first=${first%%,*}
if [[ -z "$first" ]]; then
  echo "gpu_device.sh: neither CUDA_VISIBLE_DEVICES nor SLURM_JOB_GPUS is set; no GPU to name" >&2
  exit 69
fi
if [[ "$first" == GPU-* ]]; then
  echo "uuid:${first#GPU-}"
  exit 0
fi
uuid=$(nvidia-smi --query-gpu=uuid --format=csv,noheader -i "$first")
echo "uuid:${uuid#GPU-}"
