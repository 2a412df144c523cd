#include "vkunroll/runtime/command_stream.hpp"

#include <algorithm>
#include <cstring>
#include <cstdlib>
#include <sstream>

#include "vkunroll/base/env.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/profiler.hpp"

namespace vkunroll {

namespace {
constexpr uint32_t kSetsPerPool = 256;
constexpr uint32_t kDescriptorsPerSet = 16;
constexpr uint32_t kUniformsPerSet = Pipeline::kMaxUniformBindings;  // pool sizing
constexpr uint32_t kTexelsPerSet = Pipeline::kMaxTexelBindings;
constexpr uint32_t kMaxDispatchesPerSubmit = 2048;  // timestamp pairs per query pool

// A full-size model pass on a software rasterizer can take minutes.
double default_timeout() { return env::seconds("VKUNROLL_FENCE_TIMEOUT_S", 600.0, 1e6); }

}  // namespace

CommandStream::CommandStream(Context& ctx, Profiler* profiler)
    : ctx_(ctx), profiler_(profiler), timeout_s_(default_timeout()) {
  VkCommandPoolCreateInfo pci{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pci.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pci.queueFamilyIndex = ctx.queue_family();
  VK_CHECK(vkCreateCommandPool(ctx.device(), &pci, nullptr, &pool_));
  VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  ai.commandPool = pool_;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  VK_CHECK(vkAllocateCommandBuffers(ctx.device(), &ai, &cb_));
  VkFenceCreateInfo fci{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  VK_CHECK(vkCreateFence(ctx.device(), &fci, nullptr, &fence_));
  if (ctx.info().timestamps) {
    VkQueryPoolCreateInfo qci{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    qci.queryType = VK_QUERY_TYPE_TIMESTAMP;
    qci.queryCount = 2 * kMaxDispatchesPerSubmit;
    VK_CHECK(vkCreateQueryPool(ctx.device(), &qci, nullptr, &queries_));
    query_capacity_ = qci.queryCount;
  }
}

CommandStream::~CommandStream() {
  VkDevice d = ctx_.device();
  if (queries_) vkDestroyQueryPool(d, queries_, nullptr);
  for (const auto& v : views_) vkDestroyBufferView(d, v.view, nullptr);
  for (auto p : desc_pools_) vkDestroyDescriptorPool(d, p, nullptr);
  if (fence_) vkDestroyFence(d, fence_, nullptr);
  if (pool_) vkDestroyCommandPool(d, pool_, nullptr);
}

VkDescriptorSet CommandStream::allocate_set(VkDescriptorSetLayout layout, uint32_t bindings) {
  if (bindings > kDescriptorsPerSet) throw Error("a dispatch binds more than 16 buffers");
  if (desc_pools_.empty() || desc_pool_used_ >= kSetsPerPool) {
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
    desc_pools_.push_back(pool);
    desc_pool_used_ = 0;
  }
  VkDescriptorSetAllocateInfo ai{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  ai.descriptorPool = desc_pools_.back();
  ai.descriptorSetCount = 1;
  ai.pSetLayouts = &layout;
  VkDescriptorSet set;
  VK_CHECK(vkAllocateDescriptorSets(ctx_.device(), &ai, &set));
  desc_pool_used_++;
  return set;
}

bool CommandStream::hazard_barrier(const std::vector<Span>& reads, const std::vector<Span>& writes) {
  auto hit = [](const Span& s, const std::vector<Span>& list) {
    return std::any_of(list.begin(), list.end(), [&](const Span& o) {
      return o.buffer == s.buffer && s.begin < o.end && o.begin < s.end;
    });
  };
  bool need = false;
  for (const auto& r : reads) need = need || hit(r, pending_writes_);                           // RAW
  for (const auto& w : writes) need = need || hit(w, pending_writes_) || hit(w, pending_reads_);  // WAW, WAR
  if (need) {
    pending_reads_.clear();
    pending_writes_.clear();
  }
  pending_reads_.insert(pending_reads_.end(), reads.begin(), reads.end());
  pending_writes_.insert(pending_writes_.end(), writes.begin(), writes.end());
  return need;
}

void CommandStream::dispatch(const Pipeline& pipeline, const std::vector<Arg>& args, const void* push,
                             uint32_t push_bytes, Groups groups, const DispatchInfo& info) {
  if (args.size() != pipeline.binding_count())
    throw Error("dispatch '" + info.name + "': shader " + pipeline.name() + " declares " +
                std::to_string(pipeline.binding_count()) + " buffers, " + std::to_string(args.size()) + " given");
  if (push_bytes != pipeline.push_constant_bytes())
    throw Error("dispatch '" + info.name + "': " + std::to_string(push_bytes) + " push-constant bytes given, shader " +
                pipeline.name() + " was set up for " + std::to_string(pipeline.push_constant_bytes()));
  const auto& lim = ctx_.info();
  if (groups.x == 0 || groups.y == 0 || groups.z == 0) return;  // nothing to do: an empty output
  if (groups.x > lim.max_workgroup_count[0] || groups.y > lim.max_workgroup_count[1] ||
      groups.z > lim.max_workgroup_count[2])
    throw Error("dispatch '" + info.name + "': workgroup count " + std::to_string(groups.x) + "x" +
                std::to_string(groups.y) + "x" + std::to_string(groups.z) + " exceeds the device limit");
  if (names_.size() >= kMaxDispatchesPerSubmit) submit_and_wait();  // keep submits bounded

  std::vector<Span> reads, writes;
  std::vector<VkDescriptorBufferInfo> bufs(args.size());
  std::vector<VkBufferView> views(args.size(), VK_NULL_HANDLE);
  std::vector<VkWriteDescriptorSet> w(args.size());
  // Push descriptors live in the command buffer; otherwise a set from the stream's pools per dispatch.
  const bool push_descriptors = ctx_.uses_push_descriptors();
  if (args.size() > kDescriptorsPerSet) throw Error("dispatch '" + info.name + "' binds more than 16 buffers");
  VkDescriptorSet set = push_descriptors ? VK_NULL_HANDLE : allocate_set(pipeline.set_layout(), static_cast<uint32_t>(args.size()));
  for (size_t i = 0; i < args.size(); ++i) {
    const BufferRange& r = args[i].range;
    const std::string what = "dispatch '" + info.name + "': argument " + std::to_string(i);
    if (r.buffer == VK_NULL_HANDLE) throw Error(what + " is an empty tensor");
    const DescriptorKind kind = pipeline.binding_kind(static_cast<uint32_t>(i));
    const bool uniform = kind == DescriptorKind::uniform_buffer;
    if (uniform && (r.size > lim.max_uniform_buffer_range || r.offset % lim.min_uniform_buffer_offset_alignment != 0))
      throw Error("dispatch '" + info.name + "': uniform-buffer argument " + std::to_string(i) + " spans " +
                  std::to_string(r.size) + " bytes at offset " + std::to_string(r.offset) +
                  "; at most maxUniformBufferRange (" + std::to_string(lim.max_uniform_buffer_range) +
                  ") bytes at a multiple of " + std::to_string(lim.min_uniform_buffer_offset_alignment) + " allowed");
    if (!is_texel_buffer(kind) && r.size > lim.max_storage_buffer_range)
      throw Error(what + " spans " + std::to_string(r.size) +
                  " bytes, more than maxStorageBufferRange (" + std::to_string(lim.max_storage_buffer_range) +
                  " bytes); bind it in sub-ranges");
    w[i] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    w[i].dstSet = set;
    w[i].dstBinding = static_cast<uint32_t>(i);
    w[i].descriptorCount = 1;
    w[i].descriptorType = descriptor_type(kind);
    if (is_texel_buffer(kind)) {
      views[i] = texel_view(args[i], kind, what);
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
    c.write_count = static_cast<uint32_t>(w.size());
    for (size_t i = 0; i < w.size(); ++i) pushed_.push_back({w[i].descriptorType, bufs[i], views[i]});
  } else {
    vkUpdateDescriptorSets(ctx_.device(), static_cast<uint32_t>(w.size()), w.data(), 0, nullptr);
  }
  c.push_offset = static_cast<uint32_t>(push_data_.size());
  c.push_bytes = push_bytes;
  const auto* push_begin = static_cast<const uint8_t*>(push);
  if (push_bytes) push_data_.insert(push_data_.end(), push_begin, push_begin + push_bytes);
  c.barrier = hazard_barrier(reads, writes);
  recorded_.push_back(c);
  names_.push_back(info.name);
  infos_.push_back(info);
  stages_.push_back(stage_);
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

VkBufferView CommandStream::texel_view(const Arg& a, DescriptorKind kind, const std::string& what) {
  const BufferRange& r = a.range;
  for (const auto& v : views_)
    if (v.buffer == r.buffer && v.offset == r.offset && v.size == r.size && v.format == a.texel_format) return v.view;
  const auto& lim = ctx_.info();
  const uint64_t texel = texel_bytes(a.texel_format);
  const char* kind_name = descriptor_kind_name(kind);
  if (texel == 0)
    throw Error(what + ": texel format " + std::to_string(a.texel_format) +
                " is not one of R16, R16G16, R16G16B16A16 (float), R32, R32G32, R32G32B32A32 (float, uint, sint)");
  if (r.offset % lim.min_texel_buffer_offset_alignment != 0)
    throw Error(what + " (" + kind_name + ") starts at byte offset " + std::to_string(r.offset) +
                ", not a multiple of minTexelBufferOffsetAlignment (" +
                std::to_string(lim.min_texel_buffer_offset_alignment) + ")");
  if (r.size % texel != 0 || r.size / texel > lim.max_texel_buffer_elements)
    throw Error(what + " (" + kind_name + ") spans " + std::to_string(r.size) + " bytes = " +
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
    throw Error(what + ": the device does not support texel format " + std::to_string(a.texel_format) + " as a " +
                kind_name);
  VkBufferViewCreateInfo ci{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
  ci.buffer = r.buffer;
  ci.format = a.texel_format;
  ci.offset = r.offset;
  ci.range = r.size;
  VkBufferView view = VK_NULL_HANDLE;
  VK_CHECK(vkCreateBufferView(ctx_.device(), &ci, nullptr, &view));
  views_.push_back({r.buffer, r.offset, r.size, a.texel_format, view});
  return view;
}

void CommandStream::fill(const Tensor& t, uint32_t value) {
  if (names_.size() >= kMaxDispatchesPerSubmit) submit_and_wait();
  const BufferRange r = t.range();
  Recorded c;
  c.kind = Recorded::Kind::fill;
  c.dst = r.buffer;
  c.dst_offset = r.offset;
  c.size = (r.size + 3) / 4 * 4;
  c.value = value;
  c.barrier = hazard_barrier({}, {Span{r.buffer, r.offset, r.offset + r.size}});
  recorded_.push_back(c);
  names_.push_back("fill");
  infos_.push_back({"fill", 0, static_cast<double>(r.size)});
  stages_.push_back(stage_);
}

void CommandStream::record_copy(const BufferRange& src, const BufferRange& dst, const char* name) {
  if (names_.size() >= kMaxDispatchesPerSubmit) submit_and_wait();
  Recorded c;
  c.kind = Recorded::Kind::copy;
  c.src = src.buffer;
  c.src_offset = src.offset;
  c.dst = dst.buffer;
  c.dst_offset = dst.offset;
  c.size = src.size;
  c.barrier = hazard_barrier({Span{src.buffer, src.offset, src.offset + src.size}},
                             {Span{dst.buffer, dst.offset, dst.offset + dst.size}});
  recorded_.push_back(c);
  names_.push_back(name);
  infos_.push_back({name, 0, static_cast<double>(src.size)});
  const std::string_view n(name);
  stages_.push_back(n == "upload" || n == "download" ? std::string(n) : stage_);
}

void CommandStream::upload(const Tensor& dst, size_t byte_offset, const void* data, size_t bytes) {
  if (bytes == 0) return;
  const BufferRange d = dst.range(byte_offset, bytes);  // checks the range
  // A submit inside record_copy would free the staging range before its copy ran: make room first.
  if (names_.size() >= kMaxDispatchesPerSubmit) submit_and_wait();
  staging_.push_back(ctx_.allocator().allocate(bytes, /*host_visible=*/true));
  const Allocation& s = staging_.back();
  std::memcpy(s.mapped, data, bytes);
  ctx_.traffic().upload_bytes += bytes;
  record_copy({s.buffer, s.offset, bytes}, d, "upload");
  // The host wrote the staging memory before the submission: no barrier is needed for that.
}

void CommandStream::download(const Tensor& src, size_t byte_offset, void* host, size_t bytes) {
  if (bytes == 0) return;
  const BufferRange r = src.range(byte_offset, bytes);
  if (names_.size() >= kMaxDispatchesPerSubmit) submit_and_wait();
  staging_.push_back(ctx_.allocator().allocate(bytes, /*host_visible=*/true));
  const Allocation& s = staging_.back();
  record_copy(r, {s.buffer, s.offset, bytes}, "download");
  readbacks_.push_back({host, s.mapped, bytes});
  ctx_.traffic().download_bytes += bytes;
}

std::string CommandStream::in_flight_description() {
  std::ostringstream os;
  os << names_.size() << " dispatches submitted";
  if (queries_ && !names_.empty()) {
    // The first dispatch whose end timestamp is not available was the one in flight.
    for (size_t i = 0; i < names_.size(); ++i) {
      uint64_t v[2] = {0, 0};
      VkResult r = vkGetQueryPoolResults(ctx_.device(), queries_, static_cast<uint32_t>(2 * i + 1), 1, sizeof v, v,
                                         sizeof v, VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WITH_AVAILABILITY_BIT);
      if (r != VK_SUCCESS || v[1] == 0) {
        os << "; dispatch #" << i << " '" << names_[i] << "' was in flight";
        return os.str();
      }
    }
  }
  if (!names_.empty()) os << "; first '" << names_.front() << "', last '" << names_.back() << "'";
  return os.str();
}

void CommandStream::replay() {
  VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  VK_CHECK(vkBeginCommandBuffer(cb_, &bi));
  if (queries_) vkCmdResetQueryPool(cb_, queries_, 0, query_capacity_);
  VkMemoryBarrier hazard{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
  hazard.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  hazard.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_UNIFORM_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                         VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  const VkPipelineStageFlags stages = VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT;
  std::vector<VkWriteDescriptorSet> w;
  for (size_t i = 0; i < recorded_.size(); ++i) {
    const Recorded& c = recorded_[i];
    if (c.barrier) vkCmdPipelineBarrier(cb_, stages, stages, 0, 1, &hazard, 0, nullptr, 0, nullptr);
    const uint32_t q = static_cast<uint32_t>(i) * 2;
    if (queries_) vkCmdWriteTimestamp(cb_, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, queries_, q);
    if (c.kind == Recorded::Kind::fill) {
      vkCmdFillBuffer(cb_, c.dst, c.dst_offset, c.size, c.value);
    } else if (c.kind == Recorded::Kind::copy) {
      const VkBufferCopy region{c.src_offset, c.dst_offset, c.size};
      vkCmdCopyBuffer(cb_, c.src, c.dst, 1, &region);
    } else {
      const Pipeline& p = *c.pipeline;
      vkCmdBindPipeline(cb_, VK_PIPELINE_BIND_POINT_COMPUTE, p.handle());  // waits for its build
      if (c.set) {
        vkCmdBindDescriptorSets(cb_, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout(), 0, 1, &c.set, 0, nullptr);
      } else if (c.write_count) {
        w.assign(c.write_count, VkWriteDescriptorSet{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET});
        for (uint32_t b = 0; b < c.write_count; ++b) {
          const PushedDescriptor& d = pushed_[c.first_write + b];
          w[b].dstBinding = b;
          w[b].descriptorCount = 1;
          w[b].descriptorType = d.type;
          if (d.view) w[b].pTexelBufferView = &d.view;
          else w[b].pBufferInfo = &d.buffer;
        }
        vkCmdPushDescriptorSetKHR(cb_, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout(), 0, c.write_count, w.data());
      }
      if (c.push_bytes)
        vkCmdPushConstants(cb_, p.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, c.push_bytes, push_data_.data() + c.push_offset);
      vkCmdDispatch(cb_, c.groups.x, c.groups.y, c.groups.z);
    }
    if (queries_) vkCmdWriteTimestamp(cb_, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, queries_, q + 1);
  }
  if (!readbacks_.empty()) {
    // The downloads' copies must be visible to the host reads after the fence.
    VkMemoryBarrier mb{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    mb.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    mb.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
    vkCmdPipelineBarrier(cb_, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &mb, 0, nullptr, 0, nullptr);
  }
  VK_CHECK(vkEndCommandBuffer(cb_));
}

void CommandStream::submit_and_wait() {
  if (recorded_.empty()) return;
  try {
    replay();  // before the wait's clock: the pipeline builds it waits for count as builds
  } catch (...) {
    reset();
    throw;
  }
  struct WaitClock {  // counts the wait also when the submission throws
    DeviceTraffic& traffic;
    Clock::time_point t0;
    ~WaitClock() { traffic.wait_ms += ms_since(t0); }
  } wait_clock{ctx_.traffic(), Clock::now()};
  VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cb_;
  VkResult r = ctx_.faults().next(FaultInjection::Site::submit);
  if (r == VK_SUCCESS) r = vkQueueSubmit(ctx_.queue(), 1, &si, fence_);
  ctx_.traffic().submits++;
  if (r != VK_SUCCESS) {
    const std::string what = in_flight_description();
    reset();
    throw_vk_error(r, "vkQueueSubmit", __FILE__, __LINE__, what);
  }
  const auto timeout_ns = static_cast<uint64_t>(std::max(0.0, timeout_s_) * 1e9);
  r = vkWaitForFences(ctx_.device(), 1, &fence_, VK_TRUE, timeout_ns);
  if (r == VK_TIMEOUT) {
    const std::string what = in_flight_description();
    vkDeviceWaitIdle(ctx_.device());  // the fence and pools cannot be reset while in use
    reset();
    throw VulkanError(VK_TIMEOUT, "GPU work did not finish within " + std::to_string(timeout_s_) +
                                      " s (VKUNROLL_FENCE_TIMEOUT_S): " + what);
  }
  if (r != VK_SUCCESS) {
    const std::string what = (r == VK_ERROR_DEVICE_LOST ? "device lost; " : "") + in_flight_description();
    reset();
    throw_vk_error(r, "vkWaitForFences", __FILE__, __LINE__, what);
  }
  for (const Readback& rb : readbacks_) std::memcpy(rb.host, rb.staging, rb.bytes);
  if (queries_ && !names_.empty()) {
    std::vector<uint64_t> ts(names_.size() * 2);
    VK_CHECK(vkGetQueryPoolResults(ctx_.device(), queries_, 0, static_cast<uint32_t>(ts.size()),
                                   ts.size() * sizeof(uint64_t), ts.data(), sizeof(uint64_t),
                                   VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
    const double period = ctx_.info().timestamp_period_ns;
    for (size_t i = 0; i < names_.size(); ++i) {
      const double ms = static_cast<double>(ts[2 * i + 1] - ts[2 * i]) * period * 1e-6;
      ctx_.traffic().gpu_ms += ms;
      ctx_.traffic().gpu_ms_by_stage[stages_[i]] += ms;
      if (profiler_) profiler_->record(infos_[i].name, ms, infos_[i].flop, infos_[i].bytes);
    }
  }
  reset();
}

void CommandStream::reset() {
  vkResetFences(ctx_.device(), 1, &fence_);
  vkResetCommandBuffer(cb_, 0);
  for (auto p : desc_pools_) vkResetDescriptorPool(ctx_.device(), p, 0);
  // Keep one pool for reuse; the others return to the driver.
  while (desc_pools_.size() > 1) {
    vkDestroyDescriptorPool(ctx_.device(), desc_pools_.back(), nullptr);
    desc_pools_.pop_back();
  }
  desc_pool_used_ = 0;
  for (const auto& v : views_) vkDestroyBufferView(ctx_.device(), v.view, nullptr);
  views_.clear();
  for (const Allocation& a : staging_) ctx_.allocator().free(a);
  staging_.clear();
  readbacks_.clear();
  recorded_.clear();
  pushed_.clear();
  push_data_.clear();
  names_.clear();
  infos_.clear();
  stages_.clear();
  pending_reads_.clear();
  pending_writes_.clear();
}

}  // namespace vkunroll
