// SPIR-V modules embedded by cmake/Shaders.cmake as null-terminated tables (one per layer that owns
// shaders: kernels/shaders.hpp, the tests' own), and what the runtime reads from a module.
#pragma once
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace vkunroll {

struct ShaderModuleBlob {
  const char* name;
  const uint32_t* words;
  size_t word_count;
};

// The module named `name` (the stem of its .comp file) in a table ending with {nullptr}; throws
// Error naming the shader and the table if absent.
const ShaderModuleBlob& find_shader(const ShaderModuleBlob* table, std::string_view table_name, std::string_view name);

// Descriptor bindings (set 0) declared by a module, read from its OpDecorate Binding words.
std::vector<uint32_t> spirv_storage_bindings(std::span<const uint32_t> words);

// What a set-0 binding of a module is, from its SPIR-V declaration:
// - storage_buffer: `buffer` block (BufferBlock decoration or the StorageBuffer class);
// - uniform_buffer: `uniform` block (Uniform class, Block decoration);
// - uniform_texel_buffer: `uniform samplerBuffer` / `textureBuffer` (an image of Dim Buffer, sampled);
// - storage_texel_buffer: `imageBuffer` (an image of Dim Buffer, read/written with imageLoad/Store).
enum class DescriptorKind : uint8_t { storage_buffer, uniform_buffer, uniform_texel_buffer, storage_texel_buffer };
const char* descriptor_kind_name(DescriptorKind k);
inline bool is_texel_buffer(DescriptorKind k) {
  return k == DescriptorKind::uniform_texel_buffer || k == DescriptorKind::storage_texel_buffer;
}

struct SpirvBinding {
  uint32_t binding = 0;
  DescriptorKind kind = DescriptorKind::storage_buffer;
  bool operator==(const SpirvBinding&) const = default;
};
// The bindings sorted by number, with their kinds; throws on a malformed module.
std::vector<SpirvBinding> spirv_bindings(std::span<const uint32_t> words);

}  // namespace vkunroll
