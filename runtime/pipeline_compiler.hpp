// PipelineCompiler: creates compute pipelines on worker threads, so that recording goes on while
// the driver compiles (lavapipe: LLVM, 20-160 ms a pipeline) and several compile at once.
// A CommandStream needs a pipeline's VkPipeline only when it submits; the thread that binds it
// runs it if no worker has started it, else compiles queued ones until it is done.
#pragma once
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll {

// One vkCreateComputePipelines call, shared by its Pipeline and the compiler's queue. It runs once:
// on a worker, or on a thread that needs it, or never (cancelled before it started).
class PipelineBuild {
 public:
  // `injected` (a test fault, runtime/fault_injection.hpp): the result to report instead of compiling.
  // `subgroup_size` > 0: the stage requires subgroups of that width, full (the device was checked).
  PipelineBuild(VkDevice device, VkPipelineCache cache, VkShaderModule module, VkPipelineLayout layout,
                std::vector<uint32_t> spec, VkResult injected = VK_SUCCESS, uint32_t subgroup_size = 0);
  // Compiles it here if no thread has started it; false if one has (or it is done).
  bool try_run();
  bool done() const { return state_.load() == kDone; }
  // Runs it here if no thread has started it, else waits until it is done.
  void wait();
  // Marks it done without compiling if it has not started; waits for a running one.
  void cancel();
  // Once done: the pipeline (VK_NULL_HANDLE if cancelled or failed) and the result.
  VkPipeline pipeline() const { return pipeline_; }
  VkResult result() const { return result_; }

 private:
  static constexpr int kQueued = 0, kRunning = 1, kDone = 2;
  void compile() noexcept;
  std::atomic<int> state_{kQueued};
  VkDevice device_;
  VkPipelineCache cache_;
  VkShaderModule module_;
  VkPipelineLayout layout_;
  std::vector<uint32_t> spec_;
  VkResult injected_;
  uint32_t subgroup_size_;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  VkResult result_ = VK_NOT_READY;
};

class PipelineCompiler {
 public:
  // threads = 0: every build runs on the thread that enqueues it (no workers).
  explicit PipelineCompiler(uint32_t threads);
  ~PipelineCompiler();  // builds still queued are dropped: their Pipelines cancelled them first
  PipelineCompiler(const PipelineCompiler&) = delete;
  PipelineCompiler& operator=(const PipelineCompiler&) = delete;

  void enqueue(std::shared_ptr<PipelineBuild> build);
  // Until `build` is done: runs it if nobody has, else compiles the builds queued last (those
  // needed latest) while a worker finishes it.
  void finish(PipelineBuild& build);
  uint32_t threads() const { return static_cast<uint32_t>(workers_.size()); }

 private:
  void work();
  void stop();
  std::shared_ptr<PipelineBuild> take_newest();  // the build queued last that is not done, or null
  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::shared_ptr<PipelineBuild>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace vkunroll
