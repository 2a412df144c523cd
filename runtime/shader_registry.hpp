// Embedded SPIR-V modules, looked up by the name of their shaders/*.comp file.
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

// The module compiled from shaders/<name>.comp; throws Error naming the shader if absent.
std::span<const uint32_t> find_shader(std::string_view name);
std::vector<std::string> shader_names();

// Descriptor bindings (set 0) declared by a module, read from its OpDecorate Binding words.
std::vector<uint32_t> spirv_storage_bindings(std::span<const uint32_t> words);

// A binding and whether it is a uniform buffer (a `uniform` block: Uniform storage class, Block
// decoration) rather than a storage buffer (`buffer`: BufferBlock or the StorageBuffer class).
struct SpirvBinding {
  uint32_t binding = 0;
  bool uniform = false;
  bool operator==(const SpirvBinding&) const = default;
};
// The bindings sorted by number, with their kinds; throws on a malformed module.
std::vector<SpirvBinding> spirv_bindings(std::span<const uint32_t> words);

namespace embedded {
extern const ShaderModuleBlob kShaderTable[];
}

}  // namespace vkunroll
