// Tensor: an NCHW array in device memory (a range of an Allocator block).
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "vkunroll/base/shape.hpp"
#include "vkunroll/runtime/memory.hpp"

namespace vkunroll {

class Context;

enum class DType : uint32_t { f32 = 0, f16 = 1, u32 = 2, i32 = 3 };
size_t dtype_size(DType t);
const char* dtype_name(DType t);

// A byte range of a buffer, as bound to one descriptor.
struct BufferRange {
  VkBuffer buffer = VK_NULL_HANDLE;
  VkDeviceSize offset = 0;
  VkDeviceSize size = 0;
};

// By default a tensor must fit one storage-buffer binding; `ranged` tensors may exceed it and
// are only usable by ops that bind them in sub-ranges.
enum class Binding { whole, ranged };

class Tensor {
 public:
  Tensor() = default;
  Tensor(Context& ctx, Shape shape, DType dtype = DType::f32, Binding binding = Binding::whole);
  ~Tensor();
  Tensor(Tensor&& o) noexcept;
  Tensor& operator=(Tensor&& o) noexcept;
  Tensor(const Tensor&) = delete;
  Tensor& operator=(const Tensor&) = delete;

  const Shape& shape() const { return shape_; }
  // Gives the tensor another shape of the same byte size (its memory and contents stay).
  void reshape(const Shape& s);
  DType dtype() const { return dtype_; }
  size_t bytes() const { return static_cast<size_t>(shape_.count()) * dtype_size(dtype_); }
  bool empty() const { return !alloc_; }
  Context& context() const { return *ctx_; }

  // The whole tensor, or `bytes` bytes from `byte_offset`, for binding to a dispatch.
  BufferRange range() const;
  BufferRange range(size_t byte_offset, size_t bytes) const;

  // Host <-> device copies of the whole tensor; `bytes` must equal bytes().
  void upload(const void* data, size_t bytes);
  void download(void* data, size_t bytes) const;
  // Host -> device copy of `bytes` bytes at `byte_offset`, for tensors reused with spare capacity.
  void upload_part(size_t byte_offset, const void* data, size_t bytes);
  template <class T>
  void upload(std::span<const T> v) { upload(v.data(), v.size_bytes()); }
  template <class T>
  void upload(const std::vector<T>& v) { upload(v.data(), v.size() * sizeof(T)); }
  template <class T>
  std::vector<T> download() const {
    if (sizeof(T) != dtype_size(dtype_))
      throw InternalError(std::string("Tensor::download: element size does not match dtype ") + dtype_name(dtype_));
    std::vector<T> v(static_cast<size_t>(shape_.count()));
    download(v.data(), v.size() * sizeof(T));
    return v;
  }

 private:
  void release();
  Context* ctx_ = nullptr;
  Shape shape_;
  DType dtype_ = DType::f32;
  Allocation alloc_;
};

}  // namespace vkunroll
