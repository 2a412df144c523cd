// The kernels' shaders (shaders/*.comp, embedded at build time) and their pipelines.
#pragma once
#include <cstdint>
#include <string_view>
#include <vector>

#include "vkunroll/runtime/shader_registry.hpp"

namespace vkunroll {

class Context;
class Pipeline;

// The module compiled from shaders/<name>.comp; throws Error naming it if absent.
const ShaderModuleBlob& kernel_shader(std::string_view name);

// ctx's pipeline of shaders/<shader>.comp with these specialization constants and push size;
// required_subgroup_size > 0 for a shader that assumes that subgroup width (Context::pipeline).
const Pipeline& kernel_pipeline(Context& ctx, std::string_view shader, const std::vector<uint32_t>& spec = {},
                                uint32_t push_constant_bytes = 0, uint32_t required_subgroup_size = 0);

}  // namespace vkunroll
