#include "vkunroll/runtime/pipeline.hpp"

#include <algorithm>
#include <cstring>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/base/env.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/device_limits_detail.hpp"
#include "vkunroll/runtime/pipeline_compiler.hpp"
#include "vkunroll/runtime/shader_registry.hpp"
#include "vkunroll/runtime/spirv_needs.hpp"

namespace vkunroll {

VkDescriptorType descriptor_type(DescriptorKind k) {
  switch (k) {
    case DescriptorKind::uniform_buffer: return VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER;
    case DescriptorKind::uniform_texel_buffer: return VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
    case DescriptorKind::storage_texel_buffer: return VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER;
    case DescriptorKind::storage_buffer: break;
  }
  return VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
}

namespace {
// A workgroup or shared memory over the device's limit is refused here, by the limit's Vulkan name:
// a driver would fail the compile, or (a limit a test lowered) run it as if on a bigger device.
void check_limits(const DeviceInfo& d, const std::string& shader, const SpirvComputeNeeds& n) {
  if (!n.resolved) return;
  const auto lowered = env::text(kTestLimitsVariable);
  const std::string device = "device '" + d.name + "'" + (lowered ? " (lowered for a test: " + std::string(kTestLimitsVariable) + "=" + *lowered + ")" : "");
  if (n.invocations() > d.max_workgroup_invocations)
    throw DeviceUnavailableError("pipeline '" + shader + "': a workgroup of " + std::to_string(n.invocations()) +
                                 " invocations exceeds maxComputeWorkGroupInvocations " +
                                 std::to_string(d.max_workgroup_invocations) + " of " + device);
  if (n.shared_bytes > d.max_shared_memory)
    throw DeviceUnavailableError("pipeline '" + shader + "': " + std::to_string(n.shared_bytes) +
                                 " bytes of shared memory exceed maxComputeSharedMemorySize " +
                                 std::to_string(d.max_shared_memory) + " of " + device);
}
}  // namespace

uint32_t spec_float(float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

Pipeline::Pipeline(Context& ctx, const ShaderModuleBlob& module, const std::vector<uint32_t>& spec,
                   uint32_t push_constant_bytes, uint32_t required_subgroup_size)
    : ctx_(ctx), name_(module.name), push_bytes_(push_constant_bytes), subgroup_size_(required_subgroup_size) {
  const auto t0 = Clock::now();
  const std::string& shader = name_;
  if (required_subgroup_size)
    if (const std::string why = ctx.info().subgroup_width_refusal(required_subgroup_size); !why.empty())
      throw DeviceUnavailableError("pipeline '" + shader + "': " + why);
  if (push_constant_bytes > 128 || push_constant_bytes > ctx.info().max_push_constants)
    throw InternalError("pipeline '" + shader + "': " + std::to_string(push_constant_bytes) +
                " bytes of push constants exceed the portable limit of 128");
  const std::span<const uint32_t> words(module.words, module.word_count);
  const auto bindings = spirv_bindings(words);
  for (uint32_t i = 0; i < bindings.size(); ++i) {
    if (bindings[i].binding != i) throw InternalError("shader '" + shader + "': bindings must be numbered 0..n-1");
    kinds_.push_back(bindings[i].kind);
  }
  binding_count_ = static_cast<uint32_t>(bindings.size());
  check_limits(ctx.info(), shader, spirv_compute_needs(words, spec));
  if (std::count(kinds_.begin(), kinds_.end(), DescriptorKind::uniform_buffer) > kMaxUniformBindings)
    throw InternalError("shader '" + shader + "': more than " + std::to_string(kMaxUniformBindings) + " uniform buffers");
  if (std::count_if(kinds_.begin(), kinds_.end(), is_texel_buffer) > kMaxTexelBindings)
    throw InternalError("shader '" + shader + "': more than " + std::to_string(kMaxTexelBindings) + " texel buffers");

  VkShaderModuleCreateInfo mci{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  mci.codeSize = words.size_bytes();
  mci.pCode = words.data();
  VK_CHECK(vkCreateShaderModule(ctx.device(), &mci, nullptr, &module_));

  std::vector<VkDescriptorSetLayoutBinding> lb(binding_count_);
  for (uint32_t i = 0; i < binding_count_; ++i)
    lb[i] = {i, descriptor_type(kinds_[i]), 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr};
  VkDescriptorSetLayoutCreateInfo dci{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  if (ctx.uses_push_descriptors()) dci.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_PUSH_DESCRIPTOR_BIT_KHR;
  dci.bindingCount = binding_count_;
  dci.pBindings = lb.data();
  VK_CHECK(vkCreateDescriptorSetLayout(ctx.device(), &dci, nullptr, &set_layout_));

  VkPushConstantRange pcr{VK_SHADER_STAGE_COMPUTE_BIT, 0, push_bytes_};
  VkPipelineLayoutCreateInfo lci{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  lci.setLayoutCount = 1;
  lci.pSetLayouts = &set_layout_;
  lci.pushConstantRangeCount = push_bytes_ ? 1 : 0;
  lci.pPushConstantRanges = push_bytes_ ? &pcr : nullptr;
  VK_CHECK(vkCreatePipelineLayout(ctx.device(), &lci, nullptr, &layout_));

  // The fault injector is asked here, on the recording thread, in request order: workers never touch it.
  const VkResult injected = ctx.faults().next(FaultInjection::Site::pipeline);
  build_ = std::make_shared<PipelineBuild>(ctx.device(), ctx.pipeline_cache(), module_, layout_, spec, injected,
                                           required_subgroup_size);
  ctx.pipeline_compiler().enqueue(build_);  // with no worker threads it compiles here
  ctx.traffic().pipeline_build_ms += ms_since(t0);
}

// Drivers compile the shader (lavapipe: LLVM) once per pipeline, a cost of the first frames; it counts
// as the time the recording thread spent waiting for it, so builds on workers never count twice.
VkPipeline Pipeline::handle() const {
  if (!ready_) {
    const auto t0 = Clock::now();
    ctx_.pipeline_compiler().finish(*build_);
    ctx_.traffic().pipeline_build_ms += ms_since(t0);
    if (build_->result() != VK_SUCCESS)
      throw_vk_error(build_->result(), "vkCreateComputePipelines", __FILE__, __LINE__, "shader " + name_);
    ready_ = true;
  }
  return build_->pipeline();
}

Pipeline::~Pipeline() { destroy(); }

void Pipeline::destroy() {
  VkDevice d = ctx_.device();
  if (build_) {
    build_->cancel();  // a build running on a worker is waited for: it uses the module and layout
    if (build_->pipeline()) vkDestroyPipeline(d, build_->pipeline(), nullptr);
    build_.reset();
  }
  if (layout_) vkDestroyPipelineLayout(d, layout_, nullptr);
  if (set_layout_) vkDestroyDescriptorSetLayout(d, set_layout_, nullptr);
  if (module_) vkDestroyShaderModule(d, module_, nullptr);
  layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
  module_ = VK_NULL_HANDLE;
}

}  // namespace vkunroll
