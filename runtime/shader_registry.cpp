#include "runtime/shader_registry.hpp"

#include <algorithm>
#include <map>
#include <set>

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

std::vector<SpirvBinding> spirv_bindings(std::span<const uint32_t> words) {
  constexpr uint32_t kOpDecorate = 71, kOpTypePointer = 32, kOpVariable = 59;
  constexpr uint32_t kDecorationBlock = 2, kDecorationBinding = 33;
  constexpr uint32_t kStorageUniform = 2;
  if (words.size() < 5 || words[0] != 0x07230203u) throw Error("not a SPIR-V module (bad magic)");
  std::map<uint32_t, uint32_t> binding_of;        // variable id -> binding
  std::set<uint32_t> block_structs;               // struct ids decorated Block (uniform blocks)
  std::map<uint32_t, uint32_t> pointee_of;        // Uniform-class pointer type id -> pointee
  std::map<uint32_t, uint32_t> type_of;           // variable id -> pointer type id (Uniform class only)
  for (size_t i = 5; i < words.size();) {
    const uint32_t count = words[i] >> 16, op = words[i] & 0xffffu;
    if (count == 0 || i + count > words.size()) throw Error("malformed SPIR-V module");
    if (op == kOpDecorate && count >= 4 && words[i + 2] == kDecorationBinding) binding_of[words[i + 1]] = words[i + 3];
    if (op == kOpDecorate && count >= 3 && words[i + 2] == kDecorationBlock) block_structs.insert(words[i + 1]);
    if (op == kOpTypePointer && count >= 4 && words[i + 2] == kStorageUniform) pointee_of[words[i + 1]] = words[i + 3];
    if (op == kOpVariable && count >= 4 && words[i + 3] == kStorageUniform) type_of[words[i + 2]] = words[i + 1];
    i += count;
  }
  std::vector<SpirvBinding> out;
  for (const auto& [var, binding] : binding_of) {
    bool uniform = false;  // Uniform class + Block = a uniform buffer; BufferBlock / StorageBuffer = storage
    if (auto t = type_of.find(var); t != type_of.end())
      if (auto pt = pointee_of.find(t->second); pt != pointee_of.end()) uniform = block_structs.count(pt->second) > 0;
    out.push_back({binding, uniform});
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
