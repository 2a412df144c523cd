#include "vkunroll/runtime/pipeline_compiler.hpp"

namespace vkunroll {

PipelineBuild::PipelineBuild(VkDevice device, VkPipelineCache cache, VkShaderModule module, VkPipelineLayout layout,
                             std::vector<uint32_t> spec, VkResult injected, uint32_t subgroup_size)
    : device_(device),
      cache_(cache),
      module_(module),
      layout_(layout),
      spec_(std::move(spec)),
      injected_(injected),
      subgroup_size_(subgroup_size) {}

bool PipelineBuild::try_run() {
  int expected = kQueued;
  if (!state_.compare_exchange_strong(expected, kRunning)) return false;
  compile();
  state_.store(kDone);
  state_.notify_all();
  return true;
}

void PipelineBuild::wait() {
  for (int s = state_.load(); s != kDone; s = state_.load()) {
    if (s == kQueued && try_run()) return;
    if (s == kRunning) state_.wait(kRunning);
  }
}

void PipelineBuild::cancel() {
  int expected = kQueued;
  if (state_.compare_exchange_strong(expected, kDone)) return;  // never started: never will
  wait();
}

void PipelineBuild::compile() noexcept try {
  if (injected_ != VK_SUCCESS) {
    result_ = injected_;
    return;
  }
  std::vector<VkSpecializationMapEntry> entries(spec_.size());
  for (uint32_t i = 0; i < spec_.size(); ++i) entries[i] = {i, i * 4u, 4};
  VkSpecializationInfo si{static_cast<uint32_t>(entries.size()), entries.data(), spec_.size() * 4, spec_.data()};
  VkComputePipelineCreateInfo pci{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
  pci.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
  pci.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  pci.stage.module = module_;
  pci.stage.pName = "main";
  pci.stage.pSpecializationInfo = spec_.empty() ? nullptr : &si;
  pci.layout = layout_;
  VkPipelineShaderStageRequiredSubgroupSizeCreateInfo width{
      VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_REQUIRED_SUBGROUP_SIZE_CREATE_INFO};
  if (subgroup_size_) {
    width.requiredSubgroupSize = subgroup_size_;
    pci.stage.pNext = &width;
    pci.stage.flags = VK_PIPELINE_SHADER_STAGE_CREATE_REQUIRE_FULL_SUBGROUPS_BIT;
  }
  // The pipeline cache is internally synchronized: builds on several threads may share it.
  result_ = vkCreateComputePipelines(device_, cache_, 1, &pci, nullptr, &pipeline_);
  if (result_ != VK_SUCCESS) pipeline_ = VK_NULL_HANDLE;
} catch (const std::bad_alloc&) {  // the vectors above: reported by whoever binds it
  result_ = VK_ERROR_OUT_OF_HOST_MEMORY;
}

PipelineCompiler::PipelineCompiler(uint32_t threads) {
  try {
    for (uint32_t i = 0; i < threads; ++i) workers_.emplace_back([this] { work(); });
  } catch (...) {  // no thread for the next worker: the ones started must be joined
    stop();
    throw;
  }
}

PipelineCompiler::~PipelineCompiler() { stop(); }

void PipelineCompiler::stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  for (auto& t : workers_) t.join();
  workers_.clear();
}

void PipelineCompiler::enqueue(std::shared_ptr<PipelineBuild> build) {
  if (workers_.empty()) {
    build->try_run();
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    queue_.push_back(std::move(build));
  }
  wake_.notify_one();
}

std::shared_ptr<PipelineBuild> PipelineCompiler::take_newest() {
  std::lock_guard<std::mutex> lock(mutex_);
  while (!queue_.empty()) {
    std::shared_ptr<PipelineBuild> b = std::move(queue_.back());
    queue_.pop_back();
    if (!b->done()) return b;
  }
  return nullptr;
}

void PipelineCompiler::finish(PipelineBuild& build) {
  while (!build.done()) {
    if (build.try_run()) return;
    // A worker compiles it: help with what is needed latest rather than wait idle.
    std::shared_ptr<PipelineBuild> other = take_newest();
    if (!other) {
      build.wait();
      return;
    }
    other->try_run();
  }
}

void PipelineCompiler::work() {
  for (;;) {
    std::shared_ptr<PipelineBuild> build;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      build = std::move(queue_.front());
      queue_.pop_front();
    }
    build->try_run();  // false when a thread that needed it ran it, or it was cancelled
  }
}

}  // namespace vkunroll
