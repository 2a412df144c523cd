// What a compute module asks of the device once its specialization constants (spec[i]: constant id
// i) are applied: its workgroup (LocalSize, LocalSizeId or the WorkgroupSize built-in) and its shared
// (Workgroup) variables' bytes, each at its natural size. Pipelines check it against the device's
// limits (runtime/pipeline.cpp).
#pragma once
#include <cstdint>
#include <span>
#include <vector>

namespace vkunroll {

// `resolved` is false where a size depends on an instruction this reader does not evaluate (the
// pipeline then skips its limit check; a test keeps every kernel shader resolved).
struct SpirvComputeNeeds {
  uint32_t local_size[3] = {1, 1, 1};
  uint64_t shared_bytes = 0;
  bool resolved = true;
  uint64_t invocations() const { return uint64_t{local_size[0]} * local_size[1] * local_size[2]; }
};
SpirvComputeNeeds spirv_compute_needs(std::span<const uint32_t> words, const std::vector<uint32_t>& spec);

}  // namespace vkunroll
