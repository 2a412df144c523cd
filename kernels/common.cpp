#include "kernels/common.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "runtime/context.hpp"
#include "runtime/error.hpp"

namespace vkunroll {

float apply_act(Act act, float v) {
  switch (act.kind) {
    case Activation::none: return v;
    case Activation::leaky_relu: return v >= 0.f ? v : v * act.slope;
    case Activation::tanh: return static_cast<float>(std::tanh(static_cast<double>(v)));
    case Activation::sigmoid: return static_cast<float>(1.0 / (1.0 + std::exp(-static_cast<double>(v))));
    case Activation::hardsigmoid: return std::clamp(v / 6.f + 0.5f, 0.f, 1.f);
  }
  throw Error("apply_act: unknown activation " + std::to_string(static_cast<uint32_t>(act.kind)));
}

const char* activation_name(Activation a) {
  switch (a) {
    case Activation::none: return "none";
    case Activation::leaky_relu: return "leaky_relu";
    case Activation::tanh: return "tanh";
    case Activation::sigmoid: return "sigmoid";
    case Activation::hardsigmoid: return "hardsigmoid";
  }
  return "unknown";
}

HostTensor::HostTensor(Shape s, float fill) : shape(s), data(static_cast<size_t>(s.count()), fill) {}

HostTensor::HostTensor(Shape s, std::vector<float> values) : shape(s), data(std::move(values)) {
  if (static_cast<int64_t>(data.size()) != s.count())
    throw Error("HostTensor: " + std::to_string(data.size()) + " values given for shape " + s.str() + " (" +
                std::to_string(s.count()) + " expected)");
}

Tensor HostTensor::to_device(Context& ctx) const {
  Tensor t(ctx, shape, DType::f32);
  t.upload(data);
  return t;
}

void HostTensor::upload_to(Tensor& t) const {
  if (!(t.shape() == shape) || t.dtype() != DType::f32)
    throw Error("HostTensor::upload_to: host " + shape.str() + " f32 into device " + t.shape().str() + " " +
                dtype_name(t.dtype()));
  t.upload(data);
}

HostTensor HostTensor::download(const Tensor& t) {
  if (t.dtype() != DType::f32)
    throw Error(std::string("HostTensor::download: tensor is ") + dtype_name(t.dtype()) + ", f32 expected");
  return HostTensor(t.shape(), t.download<float>());
}

namespace {
template <class S>
void check_slice_impl(const S& s, const std::string& op, const std::string& what) {
  if (!s.t) throw Error(op + ": " + what + " has no tensor");
  const Shape& f = s.tensor_shape();
  if (s.c0 < 0 || s.n0 < 0 || s.channels() <= 0 || s.batch() <= 0 || s.c0 + s.channels() > f.c ||
      s.n0 + s.batch() > f.n)
    throw Error(op + ": " + what + " slice channels [" + std::to_string(s.c0) + ", " +
                std::to_string(s.c0 + s.channels()) + ") batch [" + std::to_string(s.n0) + ", " +
                std::to_string(s.n0 + s.batch()) + ") is not inside its tensor " + f.str());
}
}  // namespace

void check_slice(const Slice& s, const std::string& op, const std::string& what) {
  check_slice_impl(s, op, what);
  if (s.t->dtype() != DType::f32)
    throw Error(op + ": " + what + " is " + dtype_name(s.t->dtype()) + ", f32 expected");
}
void check_slice(const HostSlice& s, const std::string& op, const std::string& what) {
  check_slice_impl(s, op, what);
}

BoundSlice bind_slice(const Slice& s, Access access) {
  const Shape& f = s.t->shape();
  const int64_t plane = f.h * f.w;
  const int64_t first = (s.n0 * f.c + s.c0) * plane;
  const int64_t last = ((s.n0 + s.batch() - 1) * f.c + s.c0 + s.channels()) * plane;  // one past
  // Aligned for a storage buffer and for an R32 texel-buffer view alike (both are powers of two).
  const auto& info = s.t->context().info();
  const uint64_t align = std::max<uint64_t>({4, info.min_storage_buffer_offset_alignment, info.min_texel_buffer_offset_alignment});
  const uint64_t first_bytes = static_cast<uint64_t>(first) * 4;
  const uint64_t begin = first_bytes / align * align;
  const uint64_t end = static_cast<uint64_t>(last) * 4;
  BoundSlice b;
  b.batch_stride = static_cast<uint32_t>(f.c * plane);
  if (s.t->context().options().whole_tensor_bindings && s.t->bytes() <= info.max_storage_buffer_range) {
    b.arg = {s.t->range(), access};
    b.offset = static_cast<uint32_t>(first);
    return b;
  }
  b.arg = {s.t->range(begin, end - begin), access};
  b.offset = static_cast<uint32_t>((first_bytes - begin) / 4);
  return b;
}

UniformSlabChunks uniform_slab_chunks(const DeviceInfo& info, int64_t cin, int64_t bytes_per_channel, int64_t limit) {
  UniformSlabChunks c;
  const int64_t a = static_cast<int64_t>(info.min_uniform_buffer_offset_alignment);
  c.quantum = a / std::gcd(a, bytes_per_channel);
  c.cin_pad = (cin + c.quantum - 1) / c.quantum * c.quantum;
  const int64_t m = std::min<int64_t>(cin, static_cast<int64_t>(info.max_uniform_buffer_range) / bytes_per_channel);
  c.max = m < cin ? m / c.quantum * c.quantum : m;
  c.chunk = limit <= 0 || limit >= c.max ? c.max : std::min(c.max, std::max(c.quantum, limit / c.quantum * c.quantum));
  return c;
}

}  // namespace vkunroll
