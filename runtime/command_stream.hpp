// CommandStream: records many dispatches into one command buffer with the barriers their
// buffer accesses need (read-after-write, write-after-read, write-after-write), submits once,
// and waits on a fence with a timeout. Commands are checked and their descriptors written when
// they are recorded, and written into the command buffer at submit: binding a pipeline waits for
// its build, so the context's compiler builds the submission's pipelines while it is recorded.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "vkunroll/runtime/shader_registry.hpp"
#include "vkunroll/runtime/tensor.hpp"

namespace vkunroll {

class Context;
class Pipeline;
class Profiler;

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

// What the profiler reports for a dispatch.
struct DispatchInfo {
  std::string name;   // the op, e.g. "conv2d_3x3"
  double flop = 0;    // floating-point operations (2 x multiply-adds)
  double bytes = 0;   // bytes read + written
};

struct Groups {
  uint32_t x = 1, y = 1, z = 1;
};

class CommandStream {
 public:
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
  // work: the data is copied now into staging memory the stream keeps until the submission has
  // run, so no wait is needed for earlier readers of `dst` to finish.
  void upload(const Tensor& dst, size_t byte_offset, const void* data, size_t bytes);
  // Device -> host copy, ordered likewise: `host` receives the bytes when submit_and_wait() returns
  // (it must stay valid until then).
  void download(const Tensor& src, size_t byte_offset, void* host, size_t bytes);

  size_t recorded() const { return names_.size(); }
  // Submits everything recorded, waits, feeds the profiler, and leaves the stream ready to reuse.
  // Throws on timeout or device loss, naming the dispatch that was in flight.
  void submit_and_wait();

  // The stage the next recorded commands belong to (e.g. "event_tensors"): their timestamps are
  // summed per stage in the context's traffic. Uploads and downloads are always "upload"/"download".
  void set_stage(std::string stage) { stage_ = std::move(stage); }
  const std::string& stage() const { return stage_; }

  // Seconds to wait for the fence; default from VKUNROLL_FENCE_TIMEOUT_S or 600.
  void set_timeout_seconds(double s) { timeout_s_ = s; }

 private:
  struct Span {
    VkBuffer buffer;
    VkDeviceSize begin, end;
  };
  // Whether a command with these accesses needs a barrier before it (then the pending lists restart).
  bool hazard_barrier(const std::vector<Span>& reads, const std::vector<Span>& writes);
  // Writes the recorded commands into the command buffer (waiting for their pipelines) and ends it.
  void replay();
  VkDescriptorSet allocate_set(VkDescriptorSetLayout layout, uint32_t bindings);
  void reset();
  std::string in_flight_description();
  VkBufferView texel_view(const Arg& a, DescriptorKind kind, const std::string& what);

  Context& ctx_;
  Profiler* profiler_;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cb_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  std::vector<VkDescriptorPool> desc_pools_;
  uint32_t desc_pool_used_ = 0;  // sets taken from desc_pools_.back()
  VkQueryPool queries_ = VK_NULL_HANDLE;
  uint32_t query_capacity_ = 0;
  double timeout_s_;
  // The commands of this submission, in order (names_[i] is command i's), until replay().
  struct Recorded {
    enum class Kind : uint8_t { dispatch, fill, copy } kind = Kind::dispatch;
    bool barrier = false;  // a hazard barrier before it
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
  std::vector<Recorded> recorded_;
  std::vector<PushedDescriptor> pushed_;
  std::vector<uint8_t> push_data_;
  std::vector<std::string> names_;
  std::vector<DispatchInfo> infos_;
  std::vector<std::string> stages_;  // each recorded command's stage
  std::string stage_;
  std::vector<Span> pending_reads_, pending_writes_;
  // Buffer views of this submission's texel-buffer arguments (one per buffer, range and format),
  // destroyed once the submission finished (or with the stream): a tensor freed afterwards may
  // give its buffer range to another tensor.
  struct TexelView {
    VkBuffer buffer;
    VkDeviceSize offset, size;
    VkFormat format;
    VkBufferView view;
  };
  std::vector<TexelView> views_;
  // Staging memory of this submission's transfers, and the host copies to make once it has run.
  struct Readback {
    void* host;
    const void* staging;
    size_t bytes;
  };
  std::vector<Allocation> staging_;
  std::vector<Readback> readbacks_;
  void record_copy(const BufferRange& src, const BufferRange& dst, const char* name);
  std::vector<std::pair<VkFormat, VkFormatFeatureFlags>> format_features_;  // queried once per format
};

}  // namespace vkunroll
