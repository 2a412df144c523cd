// CommandStream: records dispatches, copies and fills with the barriers their buffer accesses need,
// and submits them. Commands are checked and their descriptors written when they are recorded, and
// written into a command buffer at submit: binding a pipeline waits for its build, so the context's
// compiler builds the submission's pipelines while it is recorded.
//
// A frame recorded once: a submission whose command list (pipelines, bound ranges, push constants,
// workgroups, copies, barriers, timestamps) equals one submitted before resubmits the command buffer
// recorded then (kept, without ONE_TIME_SUBMIT) instead of recording it again. Uploads and downloads
// go through staging memory the stream keeps (a bump arena per submission slot, at the same offsets
// when a frame repeats), so a repeated frame's copies are the same commands too. The list is
// compared in full, so a replayed submission does exactly what a fresh recording would.
//
// Two submission slots: submit() hands the recording to the queue and returns; the host records the
// next submission while the device runs it, and waits only when it needs a slot back (or at
// submit_and_wait / finish). A recording is submitted on its own when it reaches kCommandsPerSubmit
// commands, so a long frame's device work starts while its host work goes on.
//
// Barriers: only where a command reads what an earlier one wrote (RAW), or writes what an earlier
// one read or wrote (WAR, WAW), since the last barrier: buffer memory barriers over the ranges
// written since then (they make those writes visible), an execution-only barrier where only reads
// came before. Each submission starts with one barrier after everything submitted before it (which
// may still be running), so hazards are tracked within a submission and a repeated frame's
// submissions are equal whatever ran before them.
#pragma once
#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/runtime/memory.hpp"
#include "vkunroll/runtime/shader_registry.hpp"
#include "vkunroll/runtime/tensor.hpp"

namespace vkunroll {

class Context;
class Pipeline;
class Profiler;
struct GpuSpan;

enum class Access { read, write, read_write };

// A buffer range bound to one binding. For a texel-buffer binding (samplerBuffer / imageBuffer in
// the shader) the stream creates a VkBufferView of `texel_format` over the range; the range's
// offset must be a multiple of minTexelBufferOffsetAlignment and its size a whole number of texels.
// Formats: R16_SFLOAT, R16G16_SFLOAT, R16G16B16A16_SFLOAT, R32_SFLOAT/UINT/SINT, R32G32_SFLOAT,
// R32G32B32A32_SFLOAT/UINT/SINT.
struct Arg {
  BufferRange range;
  Access access = Access::read;
  VkFormat texel_format = VK_FORMAT_R32_SFLOAT;
};
inline Arg in(const Tensor& t) { return {t.range(), Access::read}; }
inline Arg out(const Tensor& t) { return {t.range(), Access::write}; }
inline Arg inout(const Tensor& t) { return {t.range(), Access::read_write}; }

// What the profiler and the trace report for a dispatch.
struct DispatchInfo {
  std::string name;   // the op, e.g. "conv2d_3x3"
  double flop = 0;    // floating-point operations (2 x multiply-adds)
  double bytes = 0;   // bytes read + written
  std::string detail;  // optional, for the trace: shape and algorithm, e.g. "48x130x173->48x130x173 winograd"
};

struct Groups {
  uint32_t x = 1, y = 1, z = 1;
};

// A barrier of the last submission (tests read them): before command `before`, with the buffer
// ranges whose writes it makes visible (none: an execution-only barrier, after reads).
struct BarrierNote {
  uint32_t before = 0;
  std::vector<BufferRange> ranges;
  VkPipelineStageFlags src = 0, dst = 0;
};

class CommandStream {
 public:
  // Commands per submission before the stream submits on its own (and timestamp pairs per slot).
  static constexpr uint32_t kCommandsPerSubmit = 256;

  explicit CommandStream(Context& ctx, Profiler* profiler = nullptr);
  ~CommandStream();
  CommandStream(const CommandStream&) = delete;
  CommandStream& operator=(const CommandStream&) = delete;

  void dispatch(const Pipeline& pipeline, const std::vector<Arg>& args, const void* push, uint32_t push_bytes,
                Groups groups, const DispatchInfo& info);
  template <class P>
  void dispatch(const Pipeline& pipeline, const std::vector<Arg>& args, const P& push, Groups groups,
                const DispatchInfo& info) {
    dispatch(pipeline, args, &push, sizeof(P), groups, info);
  }
  void fill(const Tensor& t, uint32_t value);  // vkCmdFillBuffer, e.g. zeroing accumulators
  // Host -> device copy of `bytes` bytes into `dst` at `byte_offset`, ordered with the recorded
  // work: the data is copied now into the stream's staging memory, so no wait is needed for earlier
  // readers of `dst` to finish.
  void upload(const Tensor& dst, size_t byte_offset, const void* data, size_t bytes);
  // Device -> host copy, ordered likewise: `host` receives the bytes when finish() (or
  // submit_and_wait()) returns; it must stay valid until then.
  void download(const Tensor& src, size_t byte_offset, void* host, size_t bytes);

  // Commands recorded since the last submission.
  size_t recorded() const { return recorded_.size(); }
  // Hands what was recorded to the queue and returns (a replay where it repeats an earlier
  // submission). Waits first only when both slots are in flight. Throws on a failed submission.
  void submit();
  // Waits for every submission, copies the downloads to the host and feeds the profiler and trace.
  // Throws on timeout or device loss, naming the command that was in flight.
  void finish();
  // submit() then finish(): everything recorded has run when it returns.
  void submit_and_wait();

  // The stage the next recorded commands belong to (e.g. "event_tensors"): their timestamps are
  // summed per stage in the context's traffic. Uploads and downloads are always "upload"/"download".
  void set_stage(std::string stage) { stage_ = std::move(stage); }
  const std::string& stage() const { return stage_; }
  // What the trace says about the next dispatches whose DispatchInfo gives no detail (e.g. the
  // backend's conv shape and algorithm around a conv's dispatches); empty: nothing.
  void set_detail(std::string detail) { detail_ = std::move(detail); }

  // Seconds to wait for the fence; default from VKUNROLL_FENCE_TIMEOUT_S or 600.
  void set_timeout_seconds(double s) { timeout_s_ = s; }

  // The barriers of the last submission (in the order recorded).
  const std::vector<BarrierNote>& last_barriers() const { return last_barriers_; }
  // Tests only: record no barriers at all (to show that a hazard the stream orders would race).
  void drop_barriers_for_test(bool drop) { drop_barriers_ = drop; }

 private:
  struct Span {
    VkBuffer buffer;
    VkDeviceSize begin, end;
  };
  struct Recorded {
    enum class Kind : uint8_t { dispatch, fill, copy } kind = Kind::dispatch;
    bool barrier = false;                          // a hazard barrier before it
    uint32_t barrier_first = 0, barrier_count = 0;  // its ranges, in barrier_ranges_ (none: execution only)
    const Pipeline* pipeline = nullptr;
    VkDescriptorSet set = VK_NULL_HANDLE;           // without push descriptors
    uint32_t first_write = 0, write_count = 0;      // push descriptors: into pushed_
    uint32_t push_offset = 0, push_bytes = 0;       // push constants: into push_data_
    Groups groups;
    VkBuffer src = VK_NULL_HANDLE, dst = VK_NULL_HANDLE;  // copy: src -> dst; fill: dst
    VkDeviceSize src_offset = 0, dst_offset = 0, size = 0;
    uint32_t value = 0;  // fill
  };
  struct PushedDescriptor {
    VkDescriptorType type;
    VkDescriptorBufferInfo buffer;
    VkBufferView view;
  };
  struct Note {  // what the profiler, the trace and error messages say about a recorded command
    DispatchInfo info;
    std::string stage;
    Groups groups;
    bool dispatch = true;
  };
  struct Readback {
    void* host;
    const void* staging;
    size_t bytes;
  };
  struct CachedBuffer {
    std::vector<uint64_t> key;
    VkCommandBuffer cb;
    uint64_t last_use;
  };
  // A submission slot: what one submission in flight holds, and its recorded command buffers.
  struct Slot {
    VkCommandPool pool = VK_NULL_HANDLE;
    VkFence fence = VK_NULL_HANDLE;
    VkQueryPool queries = VK_NULL_HANDLE;       // created when first timed
    VkCommandBuffer one_time = VK_NULL_HANDLE;  // fresh recordings that are not kept
    bool in_flight = false, timed = false;
    Clock::time_point submitted_at;
    std::vector<Note> notes;  // of the submission in flight
    std::vector<Readback> readbacks;
    std::vector<VkDescriptorPool> desc_pools;
    uint32_t desc_pool_used = 0;  // sets taken from desc_pools.back()
    Allocation arena;             // staging, bump-allocated from 0 for each submission
    VkDeviceSize arena_used = 0, arena_wanted = 0;
    bool arena_used_ever = false;  // a stream that never stages gets no arena
    std::vector<Allocation> overflow;  // staging past the arena this submission (it grows after)
    std::unordered_map<uint64_t, std::vector<CachedBuffer>> cache;  // content hash -> recorded
    size_t cached = 0;
  };

  // Whether a command with these accesses needs a barrier before it; if so, fills its ranges.
  bool hazard_barrier(const std::vector<Span>& reads, const std::vector<Span>& writes, VkPipelineStageFlags stage,
                      Recorded& c);
  void record_into(VkCommandBuffer cb, bool timed);
  VkCommandBuffer command_buffer_for(Slot& s, bool timed);
  std::vector<uint64_t> content_key(bool timed) const;
  VkDescriptorSet allocate_set(VkDescriptorSetLayout layout, uint32_t bindings);
  void wait_slot(Slot& s);
  void complete_slot(Slot& s);
  void release_slot(Slot& s);  // its fence, staging and descriptor pools back for the next submission
  void reset_slots();          // after a failure: nothing in flight, nothing recorded
  void fail_submission(VkResult r, const char* call, Slot& s);
  void clear_recording();
  std::string in_flight_description(const Slot& s);
  VkBufferView texel_view(const Arg& a, DescriptorKind kind, const std::string& op, size_t index);
  BufferRange staging(size_t bytes, void** mapped);
  void make_room();  // submits first when the recording is full
  void record_copy(const BufferRange& src, const BufferRange& dst, const char* name);
  void add_note(DispatchInfo info, const char* stage, Groups groups, bool dispatch);

  Context& ctx_;
  Profiler* profiler_;
  std::vector<std::unique_ptr<Slot>> slots_;
  size_t current_ = 0;    // the slot being recorded
  uint64_t use_clock_ = 0;  // LRU of cached command buffers
  double timeout_s_;
  bool drop_barriers_ = false;
  // The recording (until submit()), in order.
  std::vector<Recorded> recorded_;
  std::vector<PushedDescriptor> pushed_;
  std::vector<uint8_t> push_data_;
  std::vector<BufferRange> barrier_ranges_;
  std::vector<Note> notes_;
  std::string stage_, detail_;
  // Accesses since the last barrier of this recording.
  std::vector<Span> pending_reads_, pending_writes_;
  VkPipelineStageFlags pending_stages_ = 0;
  std::vector<BarrierNote> last_barriers_;
  // Buffer views of texel-buffer arguments (one per buffer, range and format), kept with the stream:
  // a replayed command buffer names them. The allocator's buffers live as long as the context.
  std::map<std::tuple<VkBuffer, VkDeviceSize, VkDeviceSize, VkFormat>, VkBufferView> views_;
  std::vector<std::pair<VkFormat, VkFormatFeatureFlags>> format_features_;  // queried once per format
  VkDeviceSize arena_bytes_ = 0;  // every slot's staging arena: the most any submission wanted, and headroom
};

}  // namespace vkunroll
