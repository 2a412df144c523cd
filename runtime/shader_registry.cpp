#include "vkunroll/runtime/shader_registry.hpp"

#include <algorithm>
#include <map>
#include <set>

#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll {

const ShaderModuleBlob& find_shader(const ShaderModuleBlob* table, std::string_view table_name, std::string_view name) {
  for (const ShaderModuleBlob* b = table; b->name; ++b)
    if (name == b->name) return *b;
  throw InternalError("no shader named '" + std::string(name) + "' among the " + std::string(table_name) +
              " (.comp files are embedded at build time; was it added and rebuilt?)");
}

const char* descriptor_kind_name(DescriptorKind k) {
  switch (k) {
    case DescriptorKind::storage_buffer: return "storage buffer";
    case DescriptorKind::uniform_buffer: return "uniform buffer";
    case DescriptorKind::uniform_texel_buffer: return "uniform texel buffer";
    case DescriptorKind::storage_texel_buffer: return "storage texel buffer";
  }
  return "unknown";
}

std::vector<SpirvBinding> spirv_bindings(std::span<const uint32_t> words) {
  constexpr uint32_t kOpDecorate = 71, kOpTypePointer = 32, kOpVariable = 59, kOpTypeImage = 25,
                     kOpTypeSampledImage = 27;
  constexpr uint32_t kDecorationBlock = 2, kDecorationBinding = 33;
  constexpr uint32_t kStorageUniformConstant = 0, kStorageUniform = 2;
  constexpr uint32_t kDimBuffer = 5, kSampledWithSampler = 1, kSampledStorage = 2;
  if (words.size() < 5 || words[0] != 0x07230203u) throw InternalError("not a SPIR-V module (bad magic)");
  std::map<uint32_t, uint32_t> binding_of;        // variable id -> binding
  std::set<uint32_t> block_structs;               // struct ids decorated Block (uniform blocks)
  std::map<uint32_t, uint32_t> pointee_of;        // Uniform/UniformConstant pointer type id -> pointee
  std::map<uint32_t, uint32_t> type_of;           // variable id -> pointer type id (those classes only)
  std::map<uint32_t, DescriptorKind> buffer_images;  // image type id of Dim Buffer -> its texel-buffer kind
  std::map<uint32_t, uint32_t> sampled_image_of;  // OpTypeSampledImage id -> image type id
  std::set<uint32_t> opaque_vars;                 // UniformConstant variables (images, samplers)
  for (size_t i = 5; i < words.size();) {
    const uint32_t count = words[i] >> 16, op = words[i] & 0xffffu;
    if (count == 0 || i + count > words.size()) throw InternalError("malformed SPIR-V module");
    const bool interface_class = count >= 4 && (words[i + 3] == kStorageUniform || words[i + 3] == kStorageUniformConstant);
    if (op == kOpDecorate && count >= 4 && words[i + 2] == kDecorationBinding) binding_of[words[i + 1]] = words[i + 3];
    if (op == kOpDecorate && count >= 3 && words[i + 2] == kDecorationBlock) block_structs.insert(words[i + 1]);
    if (op == kOpTypePointer && count >= 4 && (words[i + 2] == kStorageUniform || words[i + 2] == kStorageUniformConstant))
      pointee_of[words[i + 1]] = words[i + 3];
    if (op == kOpVariable && interface_class) type_of[words[i + 2]] = words[i + 1];
    if (op == kOpVariable && count >= 4 && words[i + 3] == kStorageUniformConstant) opaque_vars.insert(words[i + 2]);
    if (op == kOpTypeImage && count >= 9 && words[i + 3] == kDimBuffer) {
      if (words[i + 7] == kSampledWithSampler) buffer_images[words[i + 1]] = DescriptorKind::uniform_texel_buffer;
      else if (words[i + 7] == kSampledStorage) buffer_images[words[i + 1]] = DescriptorKind::storage_texel_buffer;
      else throw InternalError("SPIR-V buffer image %" + std::to_string(words[i + 1]) +
                       " does not say whether it is sampled or storage (Sampled = 0)");
    }
    if (op == kOpTypeSampledImage && count >= 3) sampled_image_of[words[i + 1]] = words[i + 2];
    i += count;
  }
  std::vector<SpirvBinding> out;
  for (const auto& [var, binding] : binding_of) {
    DescriptorKind kind = DescriptorKind::storage_buffer;  // BufferBlock / StorageBuffer class
    if (auto t = type_of.find(var); t != type_of.end())
      if (auto pt = pointee_of.find(t->second); pt != pointee_of.end()) {
        uint32_t pointee = pt->second;
        if (auto si = sampled_image_of.find(pointee); si != sampled_image_of.end()) pointee = si->second;
        if (block_structs.count(pointee)) kind = DescriptorKind::uniform_buffer;
        else if (auto bi = buffer_images.find(pointee); bi != buffer_images.end()) kind = bi->second;
        else if (opaque_vars.count(var))
          throw InternalError("SPIR-V binding " + std::to_string(binding) +
                      " is an image or sampler that is not a buffer; only texel buffers are supported");
      }
    out.push_back({binding, kind});
  }
  std::sort(out.begin(), out.end(), [](const SpirvBinding& a, const SpirvBinding& b) { return a.binding < b.binding; });
  return out;
}

std::vector<uint32_t> spirv_storage_bindings(std::span<const uint32_t> words) {
  std::vector<uint32_t> bindings;
  for (const auto& b : spirv_bindings(words)) bindings.push_back(b.binding);
  bindings.erase(std::unique(bindings.begin(), bindings.end()), bindings.end());
  return bindings;
}

}  // namespace vkunroll
