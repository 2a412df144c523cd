#include "vkunroll/kernels/common.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/half.hpp"

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

DType precision_dtype(Precision p) { return p == Precision::fp16 ? DType::f16 : DType::f32; }

void require_fp16(const Context& ctx, const std::string& op) {
  if (!ctx.info().storage_buffer_16bit)
    throw Error(op + ": fp16 needs the Vulkan feature storageBuffer16BitAccess (16-bit storage), which device '" +
                ctx.info().name + "' does not have; use fp32");
}

std::string shader_for(const Context& ctx, const std::string& shader, Precision p, const std::string& op) {
  if (p == Precision::fp32) return shader;
  require_fp16(ctx, op);
  return shader + "_fp16";
}

Tensor upload_weights(Context& ctx, const std::vector<float>& w, Precision p, const std::string& who) {
  const Shape s{1, 1, 1, static_cast<int64_t>(w.size())};
  if (p == Precision::fp32) return to_device(ctx, HostTensor(s, w));
  std::vector<uint16_t> h(w.size());
  for (size_t i = 0; i < w.size(); ++i) {
    if (std::fabs(w[i]) > kHalfMax)
      throw Error(who + ": weight value " + std::to_string(w[i]) + " (packed index " + std::to_string(i) +
                  ") is beyond fp16's range (+-65504); run it in fp32");
    h[i] = float_to_half(w[i]);
  }
  Tensor t(ctx, s, DType::f16);
  t.upload(h);
  return t;
}

Tensor to_device(Context& ctx, const HostTensor& host, DType dtype) {
  Tensor t(ctx, host.shape, dtype);
  upload(host, t);
  return t;
}

void upload(const HostTensor& host, Tensor& t) {
  const Shape& shape = host.shape;
  const std::vector<float>& data = host.data;
  if (!(t.shape() == shape) || (t.dtype() != DType::f32 && t.dtype() != DType::f16))
    throw Error("upload: host " + shape.str() + " into device " + t.shape().str() + " " +
                dtype_name(t.dtype()) + " (same shape, f32 or f16 expected)");
  if (t.dtype() == DType::f32) {
    t.upload(data);
    return;
  }
  std::vector<uint16_t> h(data.size());
  for (size_t i = 0; i < data.size(); ++i) {
    if (std::fabs(data[i]) > kHalfMax)  // false for NaN, which stays NaN
      throw Error("upload: value " + std::to_string(data[i]) + " at index " + std::to_string(i) +
                  " of " + shape.str() + " is beyond fp16's range (+-65504)");
    h[i] = float_to_half(data[i]);
  }
  t.upload(h);
}

HostTensor to_host(const Tensor& t) {
  if (t.dtype() == DType::f32) return HostTensor(t.shape(), t.download<float>());
  if (t.dtype() != DType::f16)
    throw Error(std::string("to_host: tensor is ") + dtype_name(t.dtype()) + ", f32 or f16 expected");
  const std::vector<uint16_t> h = t.download<uint16_t>();
  std::vector<float> f(h.size());
  for (size_t i = 0; i < h.size(); ++i) f[i] = half_to_float(h[i]);
  return HostTensor(t.shape(), std::move(f));
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
  if (s.t->dtype() != DType::f32 && s.t->dtype() != DType::f16)
    throw Error(op + ": " + what + " is " + dtype_name(s.t->dtype()) + ", f32 or f16 expected");
}

Precision slice_precision(const Slice& s) { return s.t->dtype() == DType::f16 ? Precision::fp16 : Precision::fp32; }

void check_precision(const Slice& s, Precision p, const std::string& op, const std::string& what) {
  if (s.t->dtype() != precision_dtype(p))
    throw Error(op + ": " + what + " is " + dtype_name(s.t->dtype()) + ", " + dtype_name(precision_dtype(p)) +
                " expected (" + precision_name(p) + ")");
}
void check_slice(const HostSlice& s, const std::string& op, const std::string& what) {
  check_slice_impl(s, op, what);
}

BoundSlice bind_slice(const Slice& s, Access access) {
  const Shape& f = s.t->shape();
  const int64_t plane = f.h * f.w;
  const int64_t first = (s.n0 * f.c + s.c0) * plane;
  const int64_t last = ((s.n0 + s.batch() - 1) * f.c + s.c0 + s.channels()) * plane;  // one past
  // Aligned for a storage buffer and for an R32 / R16 texel-buffer view alike (both are powers of two).
  const auto& info = s.t->context().info();
  const uint64_t elem = dtype_size(s.t->dtype());
  const uint64_t align = std::max<uint64_t>({4, info.min_storage_buffer_offset_alignment, info.min_texel_buffer_offset_alignment});
  const uint64_t first_bytes = static_cast<uint64_t>(first) * elem;
  const uint64_t begin = first_bytes / align * align;
  const uint64_t end = static_cast<uint64_t>(last) * elem;
  BoundSlice b;
  b.batch_stride = static_cast<uint32_t>(f.c * plane);
  if (s.t->context().options().whole_tensor_bindings && s.t->bytes() <= info.max_storage_buffer_range) {
    b.arg = {s.t->range(), access};
    b.offset = static_cast<uint32_t>(first);
    return b;
  }
  b.arg = {s.t->range(begin, end - begin), access};
  b.offset = static_cast<uint32_t>((first_bytes - begin) / elem);
  return b;
}


bool texel_view_fits(const DeviceInfo& info, uint64_t bytes, uint64_t texel_bytes) {
  return bytes / texel_bytes <= info.max_texel_buffer_elements;
}

std::string texel_read_shader(const Context& ctx, const std::string& shader, std::initializer_list<BoundSlice*> ins,
                              Precision prec, const TexelReadOptions& opt) {
  const uint64_t element = static_cast<uint64_t>(dtype_size(precision_dtype(prec)));
  if (!opt.texel_fetch) return shader;
  for (const BoundSlice* in : ins)
    if (!texel_view_fits(ctx.info(), in->arg.range.size, element)) return shader;
  if (prec == Precision::fp16)
    for (BoundSlice* in : ins) in->arg.texel_format = VK_FORMAT_R16_SFLOAT;
  return shader + "_texel";
}

UniformSlabChunks uniform_slab_chunks(const DeviceInfo& info, int64_t cin, int64_t bytes_per_channel, int64_t limit) {
  UniformSlabChunks c;
  // At least 16 bytes: the fp16 slabs are read as std140 uvec4s (8 weights each) from the slab start.
  const int64_t a = std::max<int64_t>(16, static_cast<int64_t>(info.min_uniform_buffer_offset_alignment));
  c.quantum = a / std::gcd(a, bytes_per_channel);
  c.cin_pad = (cin + c.quantum - 1) / c.quantum * c.quantum;
  const int64_t m = std::min<int64_t>(cin, static_cast<int64_t>(info.max_uniform_buffer_range) / bytes_per_channel);
  c.max = m < cin ? m / c.quantum * c.quantum : m;
  c.chunk = limit <= 0 || limit >= c.max ? c.max : std::min(c.max, std::max(c.quantum, limit / c.quantum * c.quantum));
  return c;
}

}  // namespace vkunroll
