// CommandStream, the submitting half: two slots in flight, the replay of repeated submissions, the
// staging arenas, and what a finished submission hands back (downloads, timestamps).
#include <algorithm>
#include <cstring>
#include <sstream>
#include <type_traits>

#include "vkunroll/base/env.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include "vkunroll/runtime/trace.hpp"

namespace vkunroll {

namespace {
constexpr size_t kSlots = 2;                    // submissions in flight: the device runs one, the host records the next
constexpr size_t kKeptPerSlot = 64;             // recorded command buffers kept per slot (least recently used go)
constexpr VkDeviceSize kStagingAlign = 64;
constexpr VkDeviceSize kArenaGranule = 1 << 20;

// A full-size model pass on a software rasterizer can take minutes.
double default_timeout() { return env::seconds("VKUNROLL_FENCE_TIMEOUT_S", 600.0, 1e6); }

template <class H>
uint64_t word(H h) {
  if constexpr (std::is_pointer_v<H>) return static_cast<uint64_t>(reinterpret_cast<uintptr_t>(h));
  else return static_cast<uint64_t>(h);
}

uint64_t hash_words(const std::vector<uint64_t>& k) {
  uint64_t h = 0x9e3779b97f4a7c15ull;
  for (uint64_t w : k) {
    h ^= w + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
    h *= 0xff51afd7ed558ccdull;
  }
  return h;
}
}  // namespace

CommandStream::CommandStream(Context& ctx, Profiler* profiler)
    : ctx_(ctx), profiler_(profiler), timeout_s_(default_timeout()) {
  for (size_t i = 0; i < kSlots; ++i) {
    auto s = std::make_unique<Slot>();
    VkCommandPoolCreateInfo pci{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pci.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pci.queueFamilyIndex = ctx.queue_family();
    VK_CHECK(vkCreateCommandPool(ctx.device(), &pci, nullptr, &s->pool));
    slots_.push_back(std::move(s));  // owned from here: the destructor cleans up after a throw below
    VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    ai.commandPool = slots_.back()->pool;
    ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    ai.commandBufferCount = 1;
    VK_CHECK(vkAllocateCommandBuffers(ctx.device(), &ai, &slots_.back()->one_time));
    VkFenceCreateInfo fci{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    VK_CHECK(vkCreateFence(ctx.device(), &fci, nullptr, &slots_.back()->fence));
  }
}

CommandStream::~CommandStream() {
  VkDevice d = ctx_.device();
  // Nothing below is destroyed while the device may still use it: a wait that timed out (or failed)
  // waits for the whole device instead (destroying an in-flight fence, pool or staging buffer was
  // undefined: VUID-vkDestroyFence-fence-01120).
  bool idle = true;
  for (auto& s : slots_)
    if (s->in_flight &&
        vkWaitForFences(d, 1, &s->fence, VK_TRUE, static_cast<uint64_t>(std::max(0.0, timeout_s_) * 1e9)) != VK_SUCCESS)
      idle = false;
  if (!idle) vkDeviceWaitIdle(d);
  for (auto& s : slots_) {
    if (s->queries) vkDestroyQueryPool(d, s->queries, nullptr);
    for (auto p : s->desc_pools) vkDestroyDescriptorPool(d, p, nullptr);
    if (s->fence) vkDestroyFence(d, s->fence, nullptr);
    if (s->pool) vkDestroyCommandPool(d, s->pool, nullptr);  // frees its command buffers, kept ones too
    for (const Allocation& a : s->overflow) ctx_.allocator().free(a);
    if (s->arena) ctx_.allocator().free(s->arena);
  }
  for (const auto& [key, view] : views_) vkDestroyBufferView(d, view, nullptr);
}

BufferRange CommandStream::staging(size_t bytes, void** mapped) {
  Slot& s = *slots_[current_];
  const VkDeviceSize at = (s.arena_used + kStagingAlign - 1) / kStagingAlign * kStagingAlign;
  s.arena_used = at + bytes;
  s.arena_used_ever = true;
  s.arena_wanted = std::max(s.arena_wanted, s.arena_used);
  if (s.arena && s.arena_used <= s.arena.size) {
    *mapped = static_cast<uint8_t*>(s.arena.mapped) + at;
    return {s.arena.buffer, s.arena.offset + at, bytes};
  }
  // Past the arena: memory of its own this time; the arena grows once the submission has run.
  s.overflow.push_back(ctx_.allocator().allocate(bytes, /*host_visible=*/true));
  *mapped = s.overflow.back().mapped;
  return {s.overflow.back().buffer, s.overflow.back().offset, bytes};
}

std::vector<uint64_t> CommandStream::content_key(bool timed) const {
  std::vector<uint64_t> k;
  k.reserve(recorded_.size() * 16 + push_data_.size() / 8 + 4);
  k.push_back(word(timed) | word(slots_[current_]->readbacks.empty()) << 1);
  for (const Recorded& c : recorded_) {
    k.push_back(word(c.kind) | word(c.barrier) << 8 | word(c.barrier_count) << 16);
    for (uint32_t b = 0; b < c.barrier_count; ++b) {
      const BufferRange& r = barrier_ranges_[c.barrier_first + b];
      k.insert(k.end(), {word(r.buffer), r.offset, r.size});
    }
    if (c.kind == Recorded::Kind::fill) {
      k.insert(k.end(), {word(c.dst), c.dst_offset, c.size, c.value});
    } else if (c.kind == Recorded::Kind::copy) {
      k.insert(k.end(), {word(c.src), c.src_offset, word(c.dst), c.dst_offset, c.size});
    } else {
      k.insert(k.end(), {word(c.pipeline), word(c.set), word(c.groups.x) | word(c.groups.y) << 32, c.groups.z,
                         word(c.write_count) | word(c.push_bytes) << 32});
      for (uint32_t b = 0; b < c.write_count; ++b) {
        const PushedDescriptor& d = pushed_[c.first_write + b];
        k.insert(k.end(), {word(d.type), word(d.buffer.buffer), d.buffer.offset, d.buffer.range, word(d.view)});
      }
      for (uint32_t o = 0; o < c.push_bytes; o += 8) {
        uint64_t w = 0;
        std::memcpy(&w, push_data_.data() + c.push_offset + o, std::min<uint32_t>(8, c.push_bytes - o));
        k.push_back(w);
      }
    }
  }
  return k;
}

void CommandStream::record_into(VkCommandBuffer cb, bool timed) {
  Slot& s = *slots_[current_];
  const uint32_t n = static_cast<uint32_t>(recorded_.size());
  if (timed) vkCmdResetQueryPool(cb, s.queries, 0, 2 * n);
  const VkPipelineStageFlags stages = VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT;
  // After everything submitted before (it may still run): the hazards are tracked within a submission,
  // so its commands, and a repeated frame's, do not depend on what came before.
  VkMemoryBarrier after_earlier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
  after_earlier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  after_earlier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_UNIFORM_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                                VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  vkCmdPipelineBarrier(cb, stages, stages, 0, 1, &after_earlier, 0, nullptr, 0, nullptr);
  std::vector<VkBufferMemoryBarrier> visible;
  std::vector<VkWriteDescriptorSet> w;
  for (uint32_t i = 0; i < n; ++i) {
    const Recorded& c = recorded_[i];
    if (c.barrier) {
      visible.assign(c.barrier_count, VkBufferMemoryBarrier{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER});
      for (uint32_t b = 0; b < c.barrier_count; ++b) {
        const BufferRange& r = barrier_ranges_[c.barrier_first + b];
        visible[b].srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
        visible[b].dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_UNIFORM_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                                   VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
        visible[b].srcQueueFamilyIndex = visible[b].dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
        visible[b].buffer = r.buffer;
        visible[b].offset = r.offset;
        visible[b].size = r.size;
      }
      // Both stages on both sides: the barrier orders everything before it, so the pending lists restart.
      vkCmdPipelineBarrier(cb, stages, stages, 0, 0, nullptr, c.barrier_count, visible.data(), 0, nullptr);
    }
    if (timed) vkCmdWriteTimestamp(cb, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, s.queries, 2 * i);
    if (c.kind == Recorded::Kind::fill) {
      vkCmdFillBuffer(cb, c.dst, c.dst_offset, c.size, c.value);
    } else if (c.kind == Recorded::Kind::copy) {
      const VkBufferCopy region{c.src_offset, c.dst_offset, c.size};
      vkCmdCopyBuffer(cb, c.src, c.dst, 1, &region);
    } else {
      const Pipeline& p = *c.pipeline;
      vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.handle());  // waits for its build
      if (c.set) {
        vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout(), 0, 1, &c.set, 0, nullptr);
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
        vkCmdPushDescriptorSetKHR(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout(), 0, c.write_count, w.data());
      }
      if (c.push_bytes)
        vkCmdPushConstants(cb, p.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, c.push_bytes, push_data_.data() + c.push_offset);
      vkCmdDispatch(cb, c.groups.x, c.groups.y, c.groups.z);
    }
    if (timed) vkCmdWriteTimestamp(cb, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, s.queries, 2 * i + 1);
  }
  if (!s.readbacks.empty()) {
    // The downloads' copies must be visible to the host reads after the fence.
    VkMemoryBarrier mb{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    mb.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    mb.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &mb, 0, nullptr, 0, nullptr);
  }
}

VkCommandBuffer CommandStream::command_buffer_for(Slot& s, bool timed) {
  auto record = [&](VkCommandBuffer cb, VkCommandBufferUsageFlags flags) {
    VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    bi.flags = flags;
    VK_CHECK(vkBeginCommandBuffer(cb, &bi));
    record_into(cb, timed);
    VK_CHECK(vkEndCommandBuffer(cb));
    return cb;
  };
  if (!ctx_.command_replay()) return record(s.one_time, VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT);
  std::vector<uint64_t> key = content_key(timed);
  const uint64_t h = hash_words(key);
  std::vector<CachedBuffer>& same = s.cache[h];
  for (CachedBuffer& c : same)
    if (c.key == key) {
      c.last_use = ++use_clock_;
      ctx_.traffic().replayed_submits++;
      ctx_.traffic().replayed_commands += recorded_.size();
      return c.cb;
    }
  // Kept: a frame that repeats replays it from its next time on. One that does not ages out.
  if (s.cached >= kKeptPerSlot) {  // the least recently used goes (the slot is idle: none is pending)
    uint64_t oldest = UINT64_MAX, oldest_hash = 0;
    for (const auto& [hash, list] : s.cache)
      for (const CachedBuffer& c : list)
        if (c.last_use < oldest) oldest = c.last_use, oldest_hash = hash;
    auto& list = s.cache[oldest_hash];
    const auto it = std::find_if(list.begin(), list.end(), [&](const CachedBuffer& c) { return c.last_use == oldest; });
    vkFreeCommandBuffers(ctx_.device(), s.pool, 1, &it->cb);
    list.erase(it);
    s.cached--;
  }
  VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  ai.commandPool = s.pool;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  VkCommandBuffer cb = VK_NULL_HANDLE;
  VK_CHECK(vkAllocateCommandBuffers(ctx_.device(), &ai, &cb));
  try {
    record(cb, 0);
  } catch (...) {
    vkFreeCommandBuffers(ctx_.device(), s.pool, 1, &cb);
    throw;
  }
  s.cache[h].push_back({std::move(key), cb, ++use_clock_});
  s.cached++;
  return cb;
}

void CommandStream::submit() {
  if (recorded_.empty()) return;
  Slot& s = *slots_[current_];
  const bool timed = ctx_.info().timestamps && (ctx_.timestamps() || profiler_);
  if (timed && !s.queries) {
    VkQueryPoolCreateInfo qci{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    qci.queryType = VK_QUERY_TYPE_TIMESTAMP;
    qci.queryCount = 2 * kCommandsPerSubmit;
    VK_CHECK(vkCreateQueryPool(ctx_.device(), &qci, nullptr, &s.queries));
  }
  VkCommandBuffer cb = VK_NULL_HANDLE;
  try {
    cb = command_buffer_for(s, timed);  // before the wait's clock: the pipeline builds it waits for count as builds
  } catch (...) {
    clear_recording();
    reset_slots();
    throw;
  }
  last_barriers_.clear();
  for (uint32_t i = 0; i < recorded_.size(); ++i)
    if (recorded_[i].barrier) {
      const Recorded& c = recorded_[i];
      const auto first = barrier_ranges_.begin() + c.barrier_first;
      last_barriers_.push_back({i, std::vector<BufferRange>(first, first + c.barrier_count),
                                VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
                                VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT});
    }
  DeviceTraffic& t = ctx_.traffic();
  for (const Note& n : notes_) ++(n.dispatch ? t.dispatches : t.transfers);
  t.barriers += last_barriers_.size();
  s.notes = std::move(notes_);
  s.timed = timed;
  clear_recording();
  const Clock::time_point t0 = Clock::now();
  s.submitted_at = t0;
  VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cb;
  VkResult r = ctx_.faults().next(FaultInjection::Site::submit);
  if (r == VK_SUCCESS) r = vkQueueSubmit(ctx_.queue(), 1, &si, s.fence);
  t.submits++;
  if (r != VK_SUCCESS) fail_submission(r, "vkQueueSubmit", s);
  s.in_flight = true;
  current_ = (current_ + 1) % slots_.size();
  struct WaitClock {  // counts the wait also when it throws
    DeviceTraffic& traffic;
    Clock::time_point t0;
    ~WaitClock() { traffic.wait_ms += ms_since(t0); }
  } wait_clock{t, t0};
  if (slots_[current_]->in_flight) {  // the host records the next submission into a free slot
    const Clock::time_point w0 = Clock::now();
    wait_slot(*slots_[current_]);
    if (Trace* trace = ctx_.trace()) trace->host_span("host waits", "wait for a slot", w0, Clock::now());
  }
}

void CommandStream::finish() {
  submit();
  if (std::none_of(slots_.begin(), slots_.end(), [](const auto& s) { return s->in_flight; })) return;
  ctx_.traffic().waits++;
  const Clock::time_point t0 = Clock::now();
  for (size_t i = 1; i <= slots_.size(); ++i) {  // oldest first
    Slot& s = *slots_[(current_ + i) % slots_.size()];
    if (!s.in_flight) continue;
    try {
      wait_slot(s);
    } catch (...) {
      ctx_.traffic().wait_ms += ms_since(t0);
      throw;
    }
  }
  ctx_.traffic().wait_ms += ms_since(t0);
  if (Trace* trace = ctx_.trace()) trace->host_span("host waits", "wait for the device", t0, Clock::now());
}

void CommandStream::submit_and_wait() { finish(); }

void CommandStream::wait_slot(Slot& s) {
  if (!s.in_flight) return;
  const auto timeout_ns = static_cast<uint64_t>(std::max(0.0, timeout_s_) * 1e9);
  const VkResult r = vkWaitForFences(ctx_.device(), 1, &s.fence, VK_TRUE, timeout_ns);
  if (r == VK_TIMEOUT) {
    const std::string what = in_flight_description(s);
    vkDeviceWaitIdle(ctx_.device());  // the fences and pools cannot be reset while in use
    reset_slots();
    throw VulkanError(VK_TIMEOUT, "GPU work did not finish within " + std::to_string(timeout_s_) +
                                      " s (VKUNROLL_FENCE_TIMEOUT_S): " + what);
  }
  if (r != VK_SUCCESS) fail_submission(r, "vkWaitForFences", s);
  complete_slot(s);
}

void CommandStream::fail_submission(VkResult r, const char* call, Slot& s) {
  const std::string what = (r == VK_ERROR_DEVICE_LOST ? "device lost; " : "") + in_flight_description(s);
  vkDeviceWaitIdle(ctx_.device());
  reset_slots();
  throw_vk_error(r, call, __FILE__, __LINE__, what);
}

void CommandStream::complete_slot(Slot& s) {
  for (const Readback& rb : s.readbacks) std::memcpy(rb.host, rb.staging, rb.bytes);
  if (s.timed && !s.notes.empty()) {
    std::vector<uint64_t> ts(s.notes.size() * 2);
    VK_CHECK(vkGetQueryPoolResults(ctx_.device(), s.queries, 0, static_cast<uint32_t>(ts.size()), ts.size() * sizeof(uint64_t),
                                   ts.data(), sizeof(uint64_t), VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
    const double period = ctx_.info().timestamp_period_ns;
    Trace* trace = ctx_.trace();
    std::vector<GpuSpan> spans;
    for (size_t i = 0; i < s.notes.size(); ++i) {
      const Note& n = s.notes[i];
      const double ms = static_cast<double>(ts[2 * i + 1] - ts[2 * i]) * period * 1e-6;
      ctx_.traffic().gpu_ms += ms;
      ctx_.traffic().gpu_ms_by_stage[n.stage] += ms;
      if (profiler_) profiler_->record(n.info.name, ms, n.info.flop, n.info.bytes);
      if (trace)
        spans.push_back({n.info.name, n.info.detail, n.stage, n.info.flop, n.info.bytes,
                         {n.dispatch ? n.groups.x : 0, n.groups.y, n.groups.z},
                         static_cast<double>(ts[2 * i]) * period, static_cast<double>(ts[2 * i + 1]) * period});
    }
    if (trace) trace->gpu_submission(s.submitted_at, spans);
  }
  release_slot(s);
  // Every slot's arena takes the most staging any submission wanted, with half again as headroom:
  // a frame whose submissions fall into the slots by turns then stages at the same offsets each time.
  const VkDeviceSize wanted = s.arena_wanted + s.arena_wanted / 2;
  arena_bytes_ = std::max(arena_bytes_, (wanted + kArenaGranule - 1) / kArenaGranule * kArenaGranule);
  s.arena_wanted = 0;
  if ((s.arena ? s.arena.size : 0) < arena_bytes_ && s.arena_used_ever) {
    if (s.arena) ctx_.allocator().free(s.arena);
    s.arena = {};
    s.arena = ctx_.allocator().allocate(arena_bytes_, true);
  }
}

void CommandStream::release_slot(Slot& s) {
  vkResetFences(ctx_.device(), 1, &s.fence);
  s.in_flight = false;
  s.notes.clear();
  s.readbacks.clear();
  for (const Allocation& a : s.overflow) ctx_.allocator().free(a);
  s.overflow.clear();
  s.arena_used = 0;
  for (auto p : s.desc_pools) vkResetDescriptorPool(ctx_.device(), p, 0);
  while (s.desc_pools.size() > 1) {  // one pool stays for reuse; the others return to the driver
    vkDestroyDescriptorPool(ctx_.device(), s.desc_pools.back(), nullptr);
    s.desc_pools.pop_back();
  }
  s.desc_pool_used = 0;
}

void CommandStream::reset_slots() {
  if (std::any_of(slots_.begin(), slots_.end(), [](const auto& s) { return s->in_flight; }))
    vkDeviceWaitIdle(ctx_.device());  // fences and pools cannot be reset while in use
  for (auto& s : slots_) {
    release_slot(*s);
    s->arena_wanted = 0;
  }
  clear_recording();
}

void CommandStream::clear_recording() {
  pending_reads_.clear();  // the next submission starts with a barrier after this one
  pending_writes_.clear();
  pending_stages_ = 0;
  recorded_.clear();
  pushed_.clear();
  push_data_.clear();
  barrier_ranges_.clear();
  notes_.clear();
}

std::string CommandStream::in_flight_description(const Slot& s) {
  std::ostringstream os;
  os << s.notes.size() << " commands submitted";
  if (s.timed && !s.notes.empty()) {
    // The first command whose end timestamp is not available was the one in flight.
    for (size_t i = 0; i < s.notes.size(); ++i) {
      uint64_t v[2] = {0, 0};
      VkResult r = vkGetQueryPoolResults(ctx_.device(), s.queries, static_cast<uint32_t>(2 * i + 1), 1, sizeof v, v, sizeof v,
                                         VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WITH_AVAILABILITY_BIT);
      if (r != VK_SUCCESS || v[1] == 0) {
        os << "; command #" << i << " '" << s.notes[i].info.name << "' was in flight";
        return os.str();
      }
    }
  }
  if (!s.notes.empty()) os << "; first '" << s.notes.front().info.name << "', last '" << s.notes.back().info.name << "'";
  return os.str();
}

}  // namespace vkunroll
