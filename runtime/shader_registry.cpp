#include "runtime/shader_registry.hpp"

#include <algorithm>

#include "runtime/error.hpp"

namespace vkunroll {

std::span<const uint32_t> find_shader(std::string_view name) {
  for (const ShaderModuleBlob* b = embedded::kShaderTable; b->name; ++b)
    if (name == b->name) return {b->words, b->word_count};
  throw Error("no embedded shader named '" + std::string(name) +
              "' (shaders/*.comp are embedded at build time; was it added and rebuilt?)");
}

std::vector<std::string> shader_names() {
  std::vector<std::string> names;
  for (const ShaderModuleBlob* b = embedded::kShaderTable; b->name; ++b) names.emplace_back(b->name);
  return names;
}

std::vector<uint32_t> spirv_storage_bindings(std::span<const uint32_t> words) {
  constexpr uint32_t kOpDecorate = 71, kDecorationBinding = 33;
  std::vector<uint32_t> bindings;
  if (words.size() < 5 || words[0] != 0x07230203u) throw Error("not a SPIR-V module (bad magic)");
  for (size_t i = 5; i < words.size();) {
    const uint32_t count = words[i] >> 16, op = words[i] & 0xffffu;
    if (count == 0 || i + count > words.size()) throw Error("malformed SPIR-V module");
    if (op == kOpDecorate && count >= 4 && words[i + 2] == kDecorationBinding)
      bindings.push_back(words[i + 3]);
    i += count;
  }
  std::sort(bindings.begin(), bindings.end());
  bindings.erase(std::unique(bindings.begin(), bindings.end()), bindings.end());
  return bindings;
}

}  // namespace vkunroll
