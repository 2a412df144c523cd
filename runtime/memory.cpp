#include "vkunroll/runtime/memory.hpp"

#include <algorithm>
#include <sstream>

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {
VkDeviceSize align_up(VkDeviceSize v, VkDeviceSize a) { return (v + a - 1) / a * a; }
}  // namespace

Allocator::Allocator(Context& ctx, VkDeviceSize block_bytes) : ctx_(ctx), block_bytes_(block_bytes) {
  // Offsets must satisfy the storage-buffer binding alignment; 256 covers every known device.
  alignment_ = std::max<VkDeviceSize>(256, ctx.info().min_storage_buffer_offset_alignment);
  VkPhysicalDeviceMemoryProperties mem{};
  vkGetPhysicalDeviceMemoryProperties(ctx.physical_device(), &mem);
  // Unified memory (lavapipe, integrated GPUs): device-local memory the host reads through its
  // caches, so tensors live there and the host maps them. A discrete GPU's resizable BAR is
  // device-local and host-visible too but uncached: host reads from it crawl (35 MB/s measured on
  // an H100), so there tensors stay device-only and copies go through cached staging memory.
  const VkMemoryPropertyFlags want = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT | VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                     VK_MEMORY_PROPERTY_HOST_COHERENT_BIT | VK_MEMORY_PROPERTY_HOST_CACHED_BIT;
  for (uint32_t i = 0; i < mem.memoryTypeCount; ++i)
    if ((mem.memoryTypes[i].propertyFlags & want) == want &&
        mem.memoryHeaps[mem.memoryTypes[i].heapIndex].size >= (1ull << 30))
      device_type_host_visible_ = true;
}

Allocator::~Allocator() {
  for (auto& b : blocks_) {
    if (b.buffer) vkDestroyBuffer(ctx_.device(), b.buffer, nullptr);
    if (b.memory) vkFreeMemory(ctx_.device(), b.memory, nullptr);
  }
}

uint32_t Allocator::memory_type(uint32_t type_bits, bool host_visible) const {
  VkPhysicalDeviceMemoryProperties mem{};
  vkGetPhysicalDeviceMemoryProperties(ctx_.physical_device(), &mem);
  auto find = [&](VkMemoryPropertyFlags flags) -> uint32_t {
    for (uint32_t i = 0; i < mem.memoryTypeCount; ++i)
      if ((type_bits & (1u << i)) && (mem.memoryTypes[i].propertyFlags & flags) == flags) return i;
    return UINT32_MAX;
  };
  const VkMemoryPropertyFlags hv = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  const VkMemoryPropertyFlags cached = VK_MEMORY_PROPERTY_HOST_CACHED_BIT;
  uint32_t t = UINT32_MAX;
  if (device_type_host_visible_) t = find(VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT | hv | cached);
  // Staging: cached host memory first (downloads read it), then any coherent host-visible memory.
  if (t == UINT32_MAX && host_visible) t = find(hv | cached);
  if (t == UINT32_MAX && host_visible) t = find(hv);
  if (t == UINT32_MAX && !host_visible) t = find(VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
  if (t == UINT32_MAX) t = find(0);
  if (t == UINT32_MAX) throw DeviceUnavailableError("no Vulkan memory type fits a storage buffer on " + ctx_.info().name);
  return t;
}

uint32_t Allocator::new_block(VkDeviceSize size, bool host_visible) {
  Block b;
  b.size = size;
  VkBufferCreateInfo bci{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  bci.size = size;
  // Every kind of binding a shader may declare (texel buffers: views over tensors, CommandStream).
  bci.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT |
              VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT | VK_BUFFER_USAGE_STORAGE_TEXEL_BUFFER_BIT |
              VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  bci.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  VK_CHECK(vkCreateBuffer(ctx_.device(), &bci, nullptr, &b.buffer));
  VkMemoryRequirements req{};
  vkGetBufferMemoryRequirements(ctx_.device(), b.buffer, &req);
  VkMemoryAllocateInfo ai{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  ai.allocationSize = req.size;
  ai.memoryTypeIndex = memory_type(req.memoryTypeBits, host_visible);
  VkResult r = ctx_.faults().next(FaultInjection::Site::allocation);
  if (r == VK_SUCCESS) r = vkAllocateMemory(ctx_.device(), &ai, nullptr, &b.memory);
  if (r != VK_SUCCESS) {
    vkDestroyBuffer(ctx_.device(), b.buffer, nullptr);
    std::ostringstream os;
    os << "allocating a " << (size >> 20) << " MiB memory block (" << (stats_.block_bytes >> 20)
       << " MiB already reserved, " << (stats_.used_bytes >> 20) << " MiB in use)";
    throw_vk_error(r, "vkAllocateMemory", __FILE__, __LINE__, os.str());
  }
  VK_CHECK(vkBindBufferMemory(ctx_.device(), b.buffer, b.memory, 0));
  VkPhysicalDeviceMemoryProperties mem{};
  vkGetPhysicalDeviceMemoryProperties(ctx_.physical_device(), &mem);
  b.host_visible = mem.memoryTypes[ai.memoryTypeIndex].propertyFlags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT;
  if (b.host_visible) {
    r = ctx_.faults().next(FaultInjection::Site::map);
    if (r == VK_SUCCESS) r = vkMapMemory(ctx_.device(), b.memory, 0, VK_WHOLE_SIZE, 0, &b.mapped);
    if (r != VK_SUCCESS) {  // the block is not kept: nothing leaks past the error
      vkFreeMemory(ctx_.device(), b.memory, nullptr);
      vkDestroyBuffer(ctx_.device(), b.buffer, nullptr);
      throw_vk_error(r, "vkMapMemory", __FILE__, __LINE__, "mapping a " + std::to_string(size >> 20) + " MiB memory block");
    }
  }
  b.free.push_back({0, size});
  stats_.block_bytes += size;
  stats_.blocks++;
  blocks_.push_back(std::move(b));
  return static_cast<uint32_t>(blocks_.size() - 1);
}

Allocation Allocator::allocate(VkDeviceSize size, bool host_visible) {
  size = align_up(std::max<VkDeviceSize>(size, 4), alignment_);
  const bool want_hv = host_visible || device_type_host_visible_;
  auto try_block = [&](uint32_t bi) -> Allocation {
    Block& b = blocks_[bi];
    if (!b.buffer || (want_hv && !b.host_visible) || (!want_hv && b.host_visible)) return {};
    for (auto it = b.free.begin(); it != b.free.end(); ++it) {
      if (it->size < size) continue;
      Allocation a{b.buffer, it->offset, size, b.mapped ? static_cast<char*>(b.mapped) + it->offset : nullptr, bi};
      it->offset += size;
      it->size -= size;
      if (it->size == 0) b.free.erase(it);
      return a;
    }
    return {};
  };
  Allocation a;
  for (uint32_t bi = 0; bi < blocks_.size() && !a; ++bi) a = try_block(bi);
  if (!a) a = try_block(new_block(std::max(size, block_bytes_), want_hv));
  stats_.used_bytes += a.size;
  stats_.peak_used_bytes = std::max(stats_.peak_used_bytes, stats_.used_bytes);
  stats_.allocations++;
  return a;
}

void Allocator::free(const Allocation& a) {
  if (!a || a.block >= blocks_.size()) return;
  Block& b = blocks_[a.block];
  auto it = b.free.begin();
  while (it != b.free.end() && it->offset < a.offset) ++it;
  it = b.free.insert(it, {a.offset, a.size});
  if (auto next = std::next(it); next != b.free.end() && it->offset + it->size == next->offset) {
    it->size += next->size;
    b.free.erase(next);
  }
  if (it != b.free.begin()) {
    auto prev = std::prev(it);
    if (prev->offset + prev->size == it->offset) {
      prev->size += it->size;
      b.free.erase(it);
    }
  }
  stats_.used_bytes -= a.size;
}

}  // namespace vkunroll
