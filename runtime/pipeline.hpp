// Pipeline: one SPIR-V module (embedded by the layer that owns it) with its specialization constants and push-constant
// size; the descriptor layout (storage, uniform and texel buffers at set 0) is derived from the module once. The
// module and layouts are made at construction; the VkPipeline is compiled by the context's PipelineCompiler, and
// handle() waits for it.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "vkunroll/runtime/vk_error.hpp"
#include "vkunroll/runtime/shader_registry.hpp"

namespace vkunroll {

class Context;
class PipelineBuild;

class Pipeline {
 public:
  static constexpr uint32_t kMaxUniformBindings = 2;  // uniform buffers one shader may declare
  static constexpr uint32_t kMaxTexelBindings = 4;    // texel buffers (uniform + storage) one shader may declare
  // spec[i] is specialization constant id i (32-bit; floats bit-cast with spec_float()).
  // required_subgroup_size > 0: subgroups of that width, full (Context::pipeline); a device that
  // cannot give them throws DeviceUnavailableError naming the device and the width.
  Pipeline(Context& ctx, const ShaderModuleBlob& shader, const std::vector<uint32_t>& spec,
           uint32_t push_constant_bytes, uint32_t required_subgroup_size = 0);
  ~Pipeline();
  Pipeline(const Pipeline&) = delete;
  Pipeline& operator=(const Pipeline&) = delete;

  const std::string& name() const { return name_; }
  // The compiled pipeline: waits for its build (or runs it, if no worker has started it) and counts
  // the time this thread spent in DeviceTraffic::pipeline_build_ms. Throws if the driver failed.
  VkPipeline handle() const;
  VkPipelineLayout layout() const { return layout_; }
  VkDescriptorSetLayout set_layout() const { return set_layout_; }
  uint32_t binding_count() const { return binding_count_; }
  // What binding i is, from the shader's declaration (storage buffer if out of range).
  DescriptorKind binding_kind(uint32_t i) const { return i < kinds_.size() ? kinds_[i] : DescriptorKind::storage_buffer; }
  bool binding_is_uniform(uint32_t i) const { return binding_kind(i) == DescriptorKind::uniform_buffer; }
  uint32_t push_constant_bytes() const { return push_bytes_; }
  uint32_t required_subgroup_size() const { return subgroup_size_; }  // 0: the device's choice

 private:
  void destroy();
  Context& ctx_;
  std::string name_;
  uint32_t binding_count_ = 0;
  std::vector<DescriptorKind> kinds_;  // per binding
  uint32_t push_bytes_ = 0;
  uint32_t subgroup_size_ = 0;
  VkShaderModule module_ = VK_NULL_HANDLE;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  std::shared_ptr<PipelineBuild> build_;
  mutable bool ready_ = false;  // handle() found the build done (the recording thread's own flag)
};

uint32_t spec_float(float f);
VkDescriptorType descriptor_type(DescriptorKind k);

}  // namespace vkunroll
