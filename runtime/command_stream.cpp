// CommandStream, the recording half: commands checked, their descriptors and barriers worked out.
// Submission, replay and completion: command_stream_submit.cpp.
#include "vkunroll/runtime/command_stream.hpp"

#include <algorithm>
#include <array>
#include <cstring>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
constexpr uint32_t kSetsPerPool = 256;
constexpr uint32_t kDescriptorsPerSet = 16;
constexpr uint32_t kUniformsPerSet = Pipeline::kMaxUniformBindings;  // pool sizing
constexpr uint32_t kTexelsPerSet = Pipeline::kMaxTexelBindings;
constexpr VkPipelineStageFlags kComputeStage = VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT;
constexpr VkPipelineStageFlags kTransferStage = VK_PIPELINE_STAGE_TRANSFER_BIT;

bool overlaps(VkBuffer buffer, VkDeviceSize begin, VkDeviceSize end, VkBuffer b2, VkDeviceSize begin2, VkDeviceSize end2) {
  return buffer == b2 && begin < end2 && begin2 < end;
}
}  // namespace

VkDescriptorSet CommandStream::allocate_set(VkDescriptorSetLayout layout, uint32_t bindings) {
  if (bindings > kDescriptorsPerSet) throw InternalError("a dispatch binds more than 16 buffers");
  Slot& s = *slots_[current_];
  if (s.desc_pools.empty() || s.desc_pool_used >= kSetsPerPool) {
    const VkDescriptorPoolSize sizes[4] = {{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kSetsPerPool * kDescriptorsPerSet},
                                           {VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, kSetsPerPool * kUniformsPerSet},
                                           {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, kSetsPerPool * kTexelsPerSet},
                                           {VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER, kSetsPerPool * kTexelsPerSet}};
    VkDescriptorPoolCreateInfo ci{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    ci.maxSets = kSetsPerPool;
    ci.poolSizeCount = 4;
    ci.pPoolSizes = sizes;
    VkDescriptorPool pool;
    VK_CHECK(vkCreateDescriptorPool(ctx_.device(), &ci, nullptr, &pool));
    s.desc_pools.push_back(pool);
    s.desc_pool_used = 0;
  }
  VkDescriptorSetAllocateInfo ai{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  ai.descriptorPool = s.desc_pools.back();
  ai.descriptorSetCount = 1;
  ai.pSetLayouts = &layout;
  VkDescriptorSet set;
  VK_CHECK(vkAllocateDescriptorSets(ctx_.device(), &ai, &set));
  s.desc_pool_used++;
  return set;
}

bool CommandStream::hazard_barrier(const std::vector<Span>& reads, const std::vector<Span>& writes,
                                   VkPipelineStageFlags stage, Recorded& c) {
  auto hit = [](const Span& s, const std::vector<Span>& list) {
    return std::any_of(list.begin(), list.end(),
                       [&](const Span& o) { return overlaps(s.buffer, s.begin, s.end, o.buffer, o.begin, o.end); });
  };
  bool need = false;
  for (const auto& r : reads) need = need || hit(r, pending_writes_);                           // RAW
  for (const auto& w : writes) need = need || hit(w, pending_writes_) || hit(w, pending_reads_);  // WAW, WAR
  if (need && !drop_barriers_) {
    // The writes since the last barrier become visible; the reads only need to have happened.
    c.barrier = true;
    c.barrier_first = static_cast<uint32_t>(barrier_ranges_.size());
    std::sort(pending_writes_.begin(), pending_writes_.end(), [](const Span& a, const Span& b) {
      return a.buffer != b.buffer ? a.buffer < b.buffer : a.begin < b.begin;
    });
    for (const Span& w : pending_writes_) {  // merged where they touch
      BufferRange* last = barrier_ranges_.size() > c.barrier_first ? &barrier_ranges_.back() : nullptr;
      if (last && last->buffer == w.buffer && w.begin <= last->offset + last->size)
        last->size = std::max(last->offset + last->size, w.end) - last->offset;
      else
        barrier_ranges_.push_back({w.buffer, w.begin, w.end - w.begin});
    }
    c.barrier_count = static_cast<uint32_t>(barrier_ranges_.size()) - c.barrier_first;
    pending_reads_.clear();
    pending_writes_.clear();
    pending_stages_ = 0;
  }
  pending_reads_.insert(pending_reads_.end(), reads.begin(), reads.end());
  pending_writes_.insert(pending_writes_.end(), writes.begin(), writes.end());
  pending_stages_ |= stage;
  return c.barrier;
}

void CommandStream::add_note(DispatchInfo info, const char* stage, Groups groups, bool dispatch) {
  if (info.detail.empty() && dispatch) info.detail = detail_;
  notes_.push_back({std::move(info), stage ? std::string(stage) : stage_, groups, dispatch});
}

void CommandStream::dispatch(const Pipeline& pipeline, const std::vector<Arg>& args, const void* push,
                             uint32_t push_bytes, Groups groups, const DispatchInfo& info) {
  if (args.size() != pipeline.binding_count())
    throw InternalError("dispatch '" + info.name + "': shader " + pipeline.name() + " declares " +
                std::to_string(pipeline.binding_count()) + " buffers, " + std::to_string(args.size()) + " given");
  if (push_bytes != pipeline.push_constant_bytes())
    throw InternalError("dispatch '" + info.name + "': " + std::to_string(push_bytes) + " push-constant bytes given, shader " +
                pipeline.name() + " was set up for " + std::to_string(pipeline.push_constant_bytes()));
  const auto& lim = ctx_.info();
  if (groups.x == 0 || groups.y == 0 || groups.z == 0) return;  // nothing to do: an empty output
  if (groups.x > lim.max_workgroup_count[0] || groups.y > lim.max_workgroup_count[1] ||
      groups.z > lim.max_workgroup_count[2])
    throw InternalError("dispatch '" + info.name + "': workgroup count " + std::to_string(groups.x) + "x" +
                std::to_string(groups.y) + "x" + std::to_string(groups.z) + " exceeds the device limit");
  if (args.size() > kDescriptorsPerSet) throw InternalError("dispatch '" + info.name + "' binds more than 16 buffers");
  make_room();

  std::vector<Span> reads, writes;
  std::array<VkDescriptorBufferInfo, kDescriptorsPerSet> bufs{};
  std::array<VkBufferView, kDescriptorsPerSet> views{};
  std::array<VkWriteDescriptorSet, kDescriptorsPerSet> w{};
  // Push descriptors live in the command buffer; otherwise a set from the slot's pools per dispatch.
  const bool push_descriptors = ctx_.uses_push_descriptors();
  VkDescriptorSet set = push_descriptors ? VK_NULL_HANDLE : allocate_set(pipeline.set_layout(), static_cast<uint32_t>(args.size()));
  for (size_t i = 0; i < args.size(); ++i) {
    const BufferRange& r = args[i].range;
    auto what = [&] { return "dispatch '" + info.name + "': argument " + std::to_string(i); };
    if (r.buffer == VK_NULL_HANDLE) throw InternalError(what() + " is an empty tensor");
    const DescriptorKind kind = pipeline.binding_kind(static_cast<uint32_t>(i));
    const bool uniform = kind == DescriptorKind::uniform_buffer;
    if (uniform && (r.size > lim.max_uniform_buffer_range || r.offset % lim.min_uniform_buffer_offset_alignment != 0))
      throw InternalError("dispatch '" + info.name + "': uniform-buffer argument " + std::to_string(i) + " spans " +
                  std::to_string(r.size) + " bytes at offset " + std::to_string(r.offset) +
                  "; at most maxUniformBufferRange (" + std::to_string(lim.max_uniform_buffer_range) +
                  ") bytes at a multiple of " + std::to_string(lim.min_uniform_buffer_offset_alignment) + " allowed");
    if (!is_texel_buffer(kind) && r.size > lim.max_storage_buffer_range)
      throw InternalError(what() + " spans " + std::to_string(r.size) + " bytes, more than maxStorageBufferRange (" +
                  std::to_string(lim.max_storage_buffer_range) + " bytes); bind it in sub-ranges");
    w[i] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    w[i].dstSet = set;
    w[i].dstBinding = static_cast<uint32_t>(i);
    w[i].descriptorCount = 1;
    w[i].descriptorType = descriptor_type(kind);
    if (is_texel_buffer(kind)) {
      views[i] = texel_view(args[i], kind, info.name, i);
      w[i].pTexelBufferView = &views[i];
    } else {
      bufs[i] = {r.buffer, r.offset, r.size};
      w[i].pBufferInfo = &bufs[i];
    }
    const Span s{r.buffer, r.offset, r.offset + r.size};
    if (args[i].access != Access::write) reads.push_back(s);
    if (args[i].access != Access::read) writes.push_back(s);
  }
  Recorded c;
  c.kind = Recorded::Kind::dispatch;
  c.pipeline = &pipeline;
  c.set = set;
  c.groups = groups;
  if (push_descriptors) {
    c.first_write = static_cast<uint32_t>(pushed_.size());
    c.write_count = static_cast<uint32_t>(args.size());
    for (size_t i = 0; i < args.size(); ++i) pushed_.push_back({w[i].descriptorType, bufs[i], views[i]});
  } else {
    vkUpdateDescriptorSets(ctx_.device(), static_cast<uint32_t>(args.size()), w.data(), 0, nullptr);
  }
  c.push_offset = static_cast<uint32_t>(push_data_.size());
  c.push_bytes = push_bytes;
  const auto* push_begin = static_cast<const uint8_t*>(push);
  if (push_bytes) push_data_.insert(push_data_.end(), push_begin, push_begin + push_bytes);
  hazard_barrier(reads, writes, kComputeStage, c);
  recorded_.push_back(c);
  add_note(info, nullptr, groups, true);
}

namespace {
uint64_t texel_bytes(VkFormat f) {
  switch (f) {
    case VK_FORMAT_R16_SFLOAT: return 2;  // fp16 inputs of the direct convs
    case VK_FORMAT_R16G16_SFLOAT: return 4;  // fp16 pixel pairs of the pointwise conv
    case VK_FORMAT_R32_SFLOAT:
    case VK_FORMAT_R32_UINT:
    case VK_FORMAT_R32_SINT: return 4;
    case VK_FORMAT_R32G32_SFLOAT:
    case VK_FORMAT_R16G16B16A16_SFLOAT: return 8;  // fp16 operands of the 1x1 GEMM
    case VK_FORMAT_R32G32B32A32_SFLOAT:
    case VK_FORMAT_R32G32B32A32_UINT:
    case VK_FORMAT_R32G32B32A32_SINT: return 16;
    default: return 0;
  }
}
}  // namespace

VkBufferView CommandStream::texel_view(const Arg& a, DescriptorKind kind, const std::string& op, size_t index) {
  const BufferRange& r = a.range;
  const auto key = std::make_tuple(r.buffer, r.offset, r.size, a.texel_format);
  if (const auto it = views_.find(key); it != views_.end()) return it->second;
  const std::string what = "dispatch '" + op + "': argument " + std::to_string(index);
  const auto& lim = ctx_.info();
  const uint64_t texel = texel_bytes(a.texel_format);
  const char* kind_name = descriptor_kind_name(kind);
  if (texel == 0)
    throw InternalError(what + ": texel format " + std::to_string(a.texel_format) +
                " is not one of R16, R16G16, R16G16B16A16 (float), R32, R32G32, R32G32B32A32 (float, uint, sint)");
  if (r.offset % lim.min_texel_buffer_offset_alignment != 0)
    throw InternalError(what + " (" + kind_name + ") starts at byte offset " + std::to_string(r.offset) +
                ", not a multiple of minTexelBufferOffsetAlignment (" +
                std::to_string(lim.min_texel_buffer_offset_alignment) + ")");
  if (r.size % texel != 0 || r.size / texel > lim.max_texel_buffer_elements)
    throw InternalError(what + " (" + kind_name + ") spans " + std::to_string(r.size) + " bytes = " +
                std::to_string(static_cast<double>(r.size) / static_cast<double>(texel)) + " texels of " +
                std::to_string(texel) + " bytes; a whole number of at most maxTexelBufferElements (" +
                std::to_string(lim.max_texel_buffer_elements) + ") allowed");
  auto ff = std::find_if(format_features_.begin(), format_features_.end(),
                         [&](const auto& p) { return p.first == a.texel_format; });
  if (ff == format_features_.end()) {
    VkFormatProperties fp{};
    vkGetPhysicalDeviceFormatProperties(ctx_.physical_device(), a.texel_format, &fp);
    format_features_.emplace_back(a.texel_format, fp.bufferFeatures);
    ff = format_features_.end() - 1;
  }
  const VkFormatFeatureFlags need = kind == DescriptorKind::uniform_texel_buffer
                                        ? VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT
                                        : VK_FORMAT_FEATURE_STORAGE_TEXEL_BUFFER_BIT;
  if ((ff->second & need) == 0)
    throw DeviceUnavailableError(what + ": the device does not support texel format " + std::to_string(a.texel_format) + " as a " +
                kind_name);
  VkBufferViewCreateInfo ci{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
  ci.buffer = r.buffer;
  ci.format = a.texel_format;
  ci.offset = r.offset;
  ci.range = r.size;
  VkBufferView view = VK_NULL_HANDLE;
  VK_CHECK(vkCreateBufferView(ctx_.device(), &ci, nullptr, &view));
  views_.emplace(key, view);
  return view;
}

void CommandStream::make_room() {
  if (recorded_.size() >= kCommandsPerSubmit) submit();
}

void CommandStream::fill(const Tensor& t, uint32_t value) {
  make_room();
  const BufferRange r = t.range();
  Recorded c;
  c.kind = Recorded::Kind::fill;
  c.dst = r.buffer;
  c.dst_offset = r.offset;
  c.size = (r.size + 3) / 4 * 4;
  c.value = value;
  hazard_barrier({}, {Span{r.buffer, r.offset, r.offset + r.size}}, kTransferStage, c);
  recorded_.push_back(c);
  add_note({"fill", 0, static_cast<double>(r.size)}, nullptr, {0, 0, 0}, false);
}

void CommandStream::record_copy(const BufferRange& src, const BufferRange& dst, const char* name) {
  Recorded c;
  c.kind = Recorded::Kind::copy;
  c.src = src.buffer;
  c.src_offset = src.offset;
  c.dst = dst.buffer;
  c.dst_offset = dst.offset;
  c.size = src.size;
  hazard_barrier({Span{src.buffer, src.offset, src.offset + src.size}}, {Span{dst.buffer, dst.offset, dst.offset + dst.size}},
                 kTransferStage, c);
  recorded_.push_back(c);
  const std::string_view n(name);
  add_note({name, 0, static_cast<double>(src.size)}, n == "upload" || n == "download" ? name : nullptr, {0, 0, 0}, false);
}

void CommandStream::upload(const Tensor& dst, size_t byte_offset, const void* data, size_t bytes) {
  if (bytes == 0) return;
  const BufferRange d = dst.range(byte_offset, bytes);  // checks the range
  make_room();  // the staging belongs to the slot whose submission holds the copy
  void* mapped = nullptr;
  const BufferRange s = staging(bytes, &mapped);
  std::memcpy(mapped, data, bytes);
  ctx_.traffic().upload_bytes += bytes;
  record_copy(s, d, "upload");
  // The host wrote the staging memory before the submission: no barrier is needed for that.
}

void CommandStream::download(const Tensor& src, size_t byte_offset, void* host, size_t bytes) {
  if (bytes == 0) return;
  const BufferRange r = src.range(byte_offset, bytes);
  make_room();
  void* mapped = nullptr;
  const BufferRange s = staging(bytes, &mapped);
  record_copy(r, s, "download");
  slots_[current_]->readbacks.push_back({host, mapped, bytes});
  ctx_.traffic().download_bytes += bytes;
}

}  // namespace vkunroll
