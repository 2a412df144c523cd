// spirv_compute_needs: a compute module's workgroup size and shared memory, with its specialization
// constants applied, so that a pipeline is refused by name on a device whose limits it exceeds
// instead of failing (or silently misbehaving) in the driver.
#include <map>
#include <optional>

#include "vkunroll/runtime/spirv_needs.hpp"
#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll {
namespace {

enum Op : uint32_t {
  kOpDecorate = 71, kOpExecutionMode = 16, kOpExecutionModeId = 331, kOpTypeBool = 20, kOpTypeInt = 21,
  kOpTypeFloat = 22, kOpTypeVector = 23, kOpTypeMatrix = 24, kOpTypeArray = 28, kOpTypeStruct = 30,
  kOpTypePointer = 32, kOpConstantTrue = 41, kOpConstantFalse = 42, kOpConstant = 43, kOpConstantComposite = 44,
  kOpSpecConstantTrue = 48, kOpSpecConstantFalse = 49, kOpSpecConstant = 50, kOpSpecConstantComposite = 51,
  kOpSpecConstantOp = 52, kOpVariable = 59,
};
constexpr uint32_t kDecorationSpecId = 1, kDecorationBuiltIn = 11, kBuiltInWorkgroupSize = 25;
constexpr uint32_t kModeLocalSize = 17, kModeLocalSizeId = 38, kStorageWorkgroup = 4;

// The integer operations glslang emits for sizes built from specialization constants.
std::optional<uint64_t> spec_op(uint32_t opcode, const std::vector<uint64_t>& a) {
  auto s = [](uint64_t v) { return static_cast<int64_t>(v); };
  const size_t n = a.size();
  if (n == 1) {
    switch (opcode) {
      case 113: case 114: return a[0];       // UConvert, SConvert
      case 126: return static_cast<uint64_t>(-s(a[0]));  // SNegate
      case 168: return uint64_t{a[0] == 0};  // LogicalNot
      case 200: return ~a[0];                // Not
    }
  }
  if (n == 2) {
    switch (opcode) {
      case 128: return a[0] + a[1];
      case 130: return a[0] - a[1];
      case 132: return a[0] * a[1];
      case 134: if (a[1]) return a[0] / a[1]; break;
      case 135: if (a[1]) return static_cast<uint64_t>(s(a[0]) / s(a[1])); break;
      case 137: if (a[1]) return a[0] % a[1]; break;
      case 166: return uint64_t{a[0] || a[1]};
      case 167: return uint64_t{a[0] && a[1]};
      case 170: return uint64_t{a[0] == a[1]};
      case 171: return uint64_t{a[0] != a[1]};
      case 172: return uint64_t{a[0] > a[1]};
      case 173: return uint64_t{s(a[0]) > s(a[1])};
      case 174: return uint64_t{a[0] >= a[1]};
      case 175: return uint64_t{s(a[0]) >= s(a[1])};
      case 176: return uint64_t{a[0] < a[1]};
      case 177: return uint64_t{s(a[0]) < s(a[1])};
      case 178: return uint64_t{a[0] <= a[1]};
      case 179: return uint64_t{s(a[0]) <= s(a[1])};
      case 194: case 195: return a[0] >> a[1];
      case 196: return a[0] << a[1];
      case 197: return a[0] | a[1];
      case 198: return a[0] ^ a[1];
      case 199: return a[0] & a[1];
    }
  }
  if (n == 3 && opcode == 169) return a[0] ? a[1] : a[2];  // Select
  return std::nullopt;
}

struct Reader {
  const std::vector<uint32_t>& spec;
  std::map<uint32_t, uint32_t> spec_id;                 // result id -> SpecId
  std::map<uint32_t, uint64_t> value;                   // scalar constants, evaluated
  std::map<uint32_t, std::vector<uint32_t>> composite;  // composite constants: their parts
  std::map<uint32_t, uint64_t> type_bytes;              // type id -> natural size; absent: unknown
  std::map<uint32_t, uint32_t> workgroup_pointee;       // Workgroup pointer type -> pointee
  uint32_t workgroup_size_id = 0;                       // the WorkgroupSize built-in's constant
  bool resolved = true;

  std::optional<uint64_t> get(uint32_t id) const {
    auto it = value.find(id);
    return it == value.end() ? std::nullopt : std::optional<uint64_t>(it->second);
  }
  // The constant's value: a specialization constant takes spec[SpecId] where given.
  uint64_t specialized(uint32_t id, uint64_t dflt) const {
    auto it = spec_id.find(id);
    return it != spec_id.end() && it->second < spec.size() ? spec[it->second] : dflt;
  }
  void scalar_constant(uint32_t op, const uint32_t* w, uint32_t count) {
    const uint32_t type = w[1], id = w[2];
    uint64_t v = count > 3 ? w[3] : 0;
    if (count > 4 && type_bytes.count(type) && type_bytes[type] == 8) v |= uint64_t{w[4]} << 32;
    if (op == kOpConstantTrue || op == kOpSpecConstantTrue) v = 1;
    if (op == kOpConstantFalse || op == kOpSpecConstantFalse) v = 0;
    value[id] = (op == kOpSpecConstant || op == kOpSpecConstantTrue || op == kOpSpecConstantFalse) ? specialized(id, v) : v;
  }
  void type(uint32_t op, const uint32_t* w, uint32_t count) {
    const uint32_t id = w[1];
    auto bytes = [&](uint32_t t) { return type_bytes.count(t) ? std::optional<uint64_t>(type_bytes[t]) : std::nullopt; };
    std::optional<uint64_t> b;
    if (op == kOpTypeBool) b = 4;
    if ((op == kOpTypeInt || op == kOpTypeFloat) && count >= 3) b = w[2] / 8;
    if ((op == kOpTypeVector || op == kOpTypeMatrix) && count >= 4)
      if (auto e = bytes(w[2])) b = *e * w[3];
    if (op == kOpTypeArray && count >= 4)
      if (auto e = bytes(w[2]); e && get(w[3])) b = *e * *get(w[3]);
    if (op == kOpTypeStruct) {
      b = 0;
      for (uint32_t k = 2; k < count && b; ++k) b = bytes(w[k]) ? std::optional<uint64_t>(*b + *bytes(w[k])) : std::nullopt;
    }
    if (b) type_bytes[id] = *b;
  }
};

}  // namespace

SpirvComputeNeeds spirv_compute_needs(std::span<const uint32_t> words, const std::vector<uint32_t>& spec) {
  if (words.size() < 5 || words[0] != 0x07230203u) throw InternalError("not a SPIR-V module (bad magic)");
  SpirvComputeNeeds needs;
  Reader r{spec};
  uint32_t local_size_ids[3] = {0, 0, 0};
  for (size_t i = 5; i < words.size();) {
    const uint32_t count = words[i] >> 16, op = words[i] & 0xffffu;
    if (count == 0 || i + count > words.size()) throw InternalError("malformed SPIR-V module");
    const uint32_t* w = &words[i];
    if (op == kOpDecorate && count >= 4 && w[2] == kDecorationSpecId) r.spec_id[w[1]] = w[3];
    if (op == kOpDecorate && count >= 4 && w[2] == kDecorationBuiltIn && w[3] == kBuiltInWorkgroupSize) r.workgroup_size_id = w[1];
    if (op == kOpExecutionMode && count >= 6 && w[2] == kModeLocalSize)
      for (int k = 0; k < 3; ++k) needs.local_size[k] = w[3 + k];
    if (op == kOpExecutionModeId && count >= 6 && w[2] == kModeLocalSizeId)
      for (int k = 0; k < 3; ++k) local_size_ids[k] = w[3 + k];
    if (op >= kOpTypeBool && op <= kOpTypeStruct) r.type(op, w, count);
    if (op == kOpConstant || op == kOpConstantTrue || op == kOpConstantFalse || op == kOpSpecConstant ||
        op == kOpSpecConstantTrue || op == kOpSpecConstantFalse)
      r.scalar_constant(op, w, count);
    if ((op == kOpConstantComposite || op == kOpSpecConstantComposite) && count >= 3)
      r.composite[w[2]] = std::vector<uint32_t>(w + 3, w + count);
    if (op == kOpSpecConstantOp && count >= 4) {
      std::vector<uint64_t> args;
      bool known = true;
      for (uint32_t k = 4; k < count; ++k) {
        if (auto v = r.get(w[k])) args.push_back(*v);
        else known = false;
      }
      if (auto v = known ? spec_op(w[3], args) : std::nullopt) r.value[w[2]] = *v;
    }
    if (op == kOpTypePointer && count >= 4 && w[2] == kStorageWorkgroup) r.workgroup_pointee[w[1]] = w[3];
    if (op == kOpVariable && count >= 4 && w[3] == kStorageWorkgroup) {
      auto pointee = r.workgroup_pointee.find(w[1]);
      auto bytes = pointee == r.workgroup_pointee.end() ? r.type_bytes.end() : r.type_bytes.find(pointee->second);
      if (bytes == r.type_bytes.end()) r.resolved = false;
      else needs.shared_bytes += bytes->second;
    }
    i += count;
  }
  for (int k = 0; k < 3; ++k)
    if (local_size_ids[k]) {
      if (auto v = r.get(local_size_ids[k])) needs.local_size[k] = static_cast<uint32_t>(*v);
      else r.resolved = false;
    }
  if (auto wg = r.composite.find(r.workgroup_size_id); r.workgroup_size_id && wg != r.composite.end()) {
    for (size_t k = 0; k < 3 && k < wg->second.size(); ++k) {  // the built-in overrides LocalSize
      if (auto v = r.get(wg->second[k])) needs.local_size[k] = static_cast<uint32_t>(*v);
      else r.resolved = false;
    }
  }
  needs.resolved = r.resolved;
  return needs;
}

}  // namespace vkunroll
