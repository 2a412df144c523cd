// Device memory: large blocks, each one VkDeviceMemory bound to one VkBuffer, sub-allocated
// first-fit. A tensor is a (buffer, offset, size) range in a block.
#pragma once
#include <cstdint>
#include <list>
#include <memory>
#include <vector>

#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll {

class Context;

struct Allocation {
  VkBuffer buffer = VK_NULL_HANDLE;
  VkDeviceSize offset = 0;
  VkDeviceSize size = 0;
  void* mapped = nullptr;  // host pointer when the memory is host-visible, else nullptr
  uint32_t block = UINT32_MAX;
  explicit operator bool() const { return buffer != VK_NULL_HANDLE; }
};

struct MemoryStats {
  uint64_t block_bytes = 0;     // reserved from the driver
  uint64_t used_bytes = 0;      // handed out to tensors now
  uint64_t peak_used_bytes = 0;
  uint32_t blocks = 0;
  uint64_t allocations = 0;     // sub-allocations made since creation
};

class Allocator {
 public:
  explicit Allocator(Context& ctx, VkDeviceSize block_bytes = 256ull << 20);
  ~Allocator();
  Allocator(const Allocator&) = delete;
  Allocator& operator=(const Allocator&) = delete;

  // host_visible=true asks for memory the host can map (staging); device memory otherwise,
  // which is host-visible too on unified-memory devices like lavapipe.
  Allocation allocate(VkDeviceSize size, bool host_visible = false);
  void free(const Allocation& a);

  bool device_memory_is_host_visible() const { return device_type_host_visible_; }
  const MemoryStats& stats() const { return stats_; }
  void reset_peak() { stats_.peak_used_bytes = stats_.used_bytes; }

 private:
  struct Range {
    VkDeviceSize offset, size;
  };
  struct Block {
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceSize size = 0;
    void* mapped = nullptr;
    bool host_visible = false;
    std::list<Range> free;  // sorted by offset, coalesced
  };
  uint32_t new_block(VkDeviceSize size, bool host_visible);
  uint32_t memory_type(uint32_t type_bits, bool host_visible) const;

  Context& ctx_;
  VkDeviceSize block_bytes_;
  VkDeviceSize alignment_;
  bool device_type_host_visible_ = false;
  std::vector<Block> blocks_;
  MemoryStats stats_;
};

}  // namespace vkunroll
