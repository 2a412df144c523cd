#include "vkunroll/runtime/tensor.hpp"

#include <cstring>
#include <sstream>

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

size_t dtype_size(DType t) { return t == DType::f16 ? 2 : 4; }

const char* dtype_name(DType t) {
  switch (t) {
    case DType::f32: return "f32";
    case DType::f16: return "f16";
    case DType::u32: return "u32";
    case DType::i32: return "i32";
  }
  return "?";
}

namespace {
// Copies between a host-visible staging allocation and a device-only allocation.
void copy_buffer(Context& ctx, BufferRange src, BufferRange dst) {
  VkCommandPoolCreateInfo pci{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pci.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
  pci.queueFamilyIndex = ctx.queue_family();
  VkCommandPool pool;
  VK_CHECK(vkCreateCommandPool(ctx.device(), &pci, nullptr, &pool));
  VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  ai.commandPool = pool;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  VkCommandBuffer cb;
  VK_CHECK(vkAllocateCommandBuffers(ctx.device(), &ai, &cb));
  VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  VK_CHECK(vkBeginCommandBuffer(cb, &bi));
  VkBufferCopy region{src.offset, dst.offset, src.size};
  vkCmdCopyBuffer(cb, src.buffer, dst.buffer, 1, &region);
  VK_CHECK(vkEndCommandBuffer(cb));
  VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cb;
  VkResult r = ctx.faults().next(FaultInjection::Site::submit);
  if (r == VK_SUCCESS) r = vkQueueSubmit(ctx.queue(), 1, &si, VK_NULL_HANDLE);
  ctx.traffic().submits++;
  if (r == VK_SUCCESS) r = vkQueueWaitIdle(ctx.queue());
  vkDestroyCommandPool(ctx.device(), pool, nullptr);
  if (r != VK_SUCCESS) throw_vk_error(r, "vkQueueSubmit", __FILE__, __LINE__, "a buffer copy");
}
}  // namespace

Tensor::Tensor(Context& ctx, Shape shape, DType dtype, Binding binding)
    : ctx_(&ctx), shape_(shape), dtype_(dtype) {
  if (shape.n <= 0 || shape.c <= 0 || shape.h <= 0 || shape.w <= 0)
    throw UsageError("Tensor: every dimension must be positive, got " + shape.str());
  const uint64_t limit = ctx.info().max_storage_buffer_range;
  if (binding == Binding::whole && bytes() > limit) {
    std::ostringstream os;
    os << "tensor " << shape.str() << " " << dtype_name(dtype) << " is " << bytes() << " bytes, more than "
       << "this device's maxStorageBufferRange of " << limit << " bytes (" << (limit >> 20)
       << " MiB) that one binding can address; use tiled execution or a smaller input";
    throw DataError(os.str());
  }
  alloc_ = ctx.allocator().allocate(bytes());
}

Tensor::~Tensor() { release(); }

Tensor::Tensor(Tensor&& o) noexcept : ctx_(o.ctx_), shape_(o.shape_), dtype_(o.dtype_), alloc_(o.alloc_) {
  o.alloc_ = {};
}

Tensor& Tensor::operator=(Tensor&& o) noexcept {
  if (this != &o) {
    release();
    ctx_ = o.ctx_;
    shape_ = o.shape_;
    dtype_ = o.dtype_;
    alloc_ = o.alloc_;
    o.alloc_ = {};
  }
  return *this;
}

void Tensor::release() {
  if (alloc_ && ctx_) ctx_->allocator().free(alloc_);
  alloc_ = {};
}

void Tensor::reshape(const Shape& s) {
  if (static_cast<size_t>(s.count()) * dtype_size(dtype_) != bytes())
    throw UsageError("Tensor::reshape: " + shape_.str() + " to " + s.str() + " changes the byte size");
  shape_ = s;
}

BufferRange Tensor::range() const { return {alloc_.buffer, alloc_.offset, bytes()}; }

BufferRange Tensor::range(size_t byte_offset, size_t nbytes) const {
  if (byte_offset + nbytes > bytes())
    throw UsageError("Tensor::range: bytes [" + std::to_string(byte_offset) + ", " + std::to_string(byte_offset + nbytes) +
                ") outside the tensor " + shape_.str() + " of " + std::to_string(bytes()) + " bytes");
  return {alloc_.buffer, alloc_.offset + byte_offset, nbytes};
}

void Tensor::upload(const void* data, size_t nbytes) {
  if (nbytes != bytes())
    throw UsageError("Tensor::upload: " + std::to_string(nbytes) + " bytes given for a tensor " + shape_.str() + " " +
                dtype_name(dtype_) + " of " + std::to_string(bytes()) + " bytes");
  ctx_->traffic().upload_bytes += nbytes;
  if (alloc_.mapped) {
    std::memcpy(alloc_.mapped, data, nbytes);
    return;
  }
  Allocation staging = ctx_->allocator().allocate(nbytes, /*host_visible=*/true);
  std::memcpy(staging.mapped, data, nbytes);
  try {
    copy_buffer(*ctx_, {staging.buffer, staging.offset, nbytes}, range());
  } catch (...) {
    ctx_->allocator().free(staging);
    throw;
  }
  ctx_->allocator().free(staging);
}

void Tensor::upload_part(size_t byte_offset, const void* data, size_t nbytes) {
  if (byte_offset > bytes() || nbytes > bytes() - byte_offset)
    throw UsageError("Tensor::upload_part: bytes [" + std::to_string(byte_offset) + ", " +
                std::to_string(byte_offset + nbytes) + ") outside the tensor " + shape_.str() + " of " +
                std::to_string(bytes()) + " bytes");
  if (nbytes == 0) return;
  ctx_->traffic().upload_bytes += nbytes;
  if (alloc_.mapped) {
    std::memcpy(static_cast<char*>(alloc_.mapped) + byte_offset, data, nbytes);
    return;
  }
  Allocation staging = ctx_->allocator().allocate(nbytes, /*host_visible=*/true);
  std::memcpy(staging.mapped, data, nbytes);
  try {
    copy_buffer(*ctx_, {staging.buffer, staging.offset, nbytes}, range(byte_offset, nbytes));
  } catch (...) {
    ctx_->allocator().free(staging);
    throw;
  }
  ctx_->allocator().free(staging);
}

void Tensor::download(void* data, size_t nbytes) const {
  if (nbytes != bytes())
    throw UsageError("Tensor::download: " + std::to_string(nbytes) + " bytes asked of a tensor " + shape_.str() + " " +
                dtype_name(dtype_) + " of " + std::to_string(bytes()) + " bytes");
  ctx_->traffic().download_bytes += nbytes;
  if (alloc_.mapped) {
    std::memcpy(data, alloc_.mapped, nbytes);
    return;
  }
  Allocation staging = ctx_->allocator().allocate(nbytes, /*host_visible=*/true);
  try {
    copy_buffer(*ctx_, range(), {staging.buffer, staging.offset, nbytes});
  } catch (...) {
    ctx_->allocator().free(staging);
    throw;
  }
  std::memcpy(data, staging.mapped, nbytes);
  ctx_->allocator().free(staging);
}

}  // namespace vkunroll
