// Shared vocabulary of the kernels: activations, host tensors (the CPU references' data), and
// slices (a channel range and a batch range of a tensor) so ops read from and write into parts
// of a larger tensor: dense concatenations cost no copy.
#pragma once
#include <cstdint>
#include <initializer_list>
#include <string>
#include <vector>

#include "vkunroll/base/host_tensor.hpp"
#include "vkunroll/base/precision.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/tensor.hpp"

namespace vkunroll {

struct DeviceInfo;

// How an op stores its data. fp32 is the reference. fp16 keeps activations, weights and scratch as
// float16 in buffers (biases, accumulators and the GEMM's M stay fp32; per op: docs/kernels.md,
// "Precision"); it needs the device feature storageBuffer16BitAccess. A slice's dtype (f32 / f16)
// says its precision.
// (Precision, precision_name and parse_precision live in base/precision.hpp.)
DType precision_dtype(Precision p);  // f32 / f16
// The embedded module of `shader` for `p` ("<shader>" or "<shader>_fp16"). Throws Error naming `op`,
// the device and the missing feature when fp16 cannot run on `ctx`'s device.
std::string shader_for(const Context& ctx, const std::string& shader, Precision p, const std::string& op);
// Throws Error naming `op` unless the device can run fp16 kernels.
void require_fp16(const Context& ctx, const std::string& op);

enum class Activation : uint32_t { none = 0, leaky_relu = 1, tanh = 2, sigmoid = 3, hardsigmoid = 4 };

struct Act {
  Activation kind = Activation::none;
  float slope = 0.f;  // negative slope of leaky_relu
};
inline Act leaky_relu(float slope) { return {Activation::leaky_relu, slope}; }

// The CPU definition every shader matches: hardsigmoid(x) = clamp(x/6 + 1/2, 0, 1) (PyTorch's).
float apply_act(Act act, float v);
const char* activation_name(Activation a);

// The profiler's share of one dispatch of a conv run as `blocks` blocks of output channels times
// chunks of input channels: flop in proportion to cin_part x cout_part, bytes split per block.
inline DispatchInfo dispatch_part(const DispatchInfo& whole, int64_t cin_part, int64_t cout_part, int64_t cin,
                                  int64_t cout, int64_t blocks) {
  return {whole.name,
          whole.flop * static_cast<double>(cin_part) * static_cast<double>(cout_part) / static_cast<double>(cin * cout),
          whole.bytes / static_cast<double>(blocks)};
}

// Workgroups of 64 for `n` invocations numbered x + y * (64 gx) in the shader (y only past the
// 65535-group limit of x), `z` deep.
inline Groups flat_groups(int64_t n, uint32_t z) {
  const int64_t g = (n + 63) / 64;
  const int64_t gx = g < 65535 ? g : 65535;
  return {static_cast<uint32_t>(gx), static_cast<uint32_t>((g + gx - 1) / gx), z};
}

// How a direct conv splits its input channels into weight slabs, each bound as one uniform buffer:
// a slab fits maxUniformBufferRange and starts at a multiple of minUniformBufferOffsetAlignment
// (64 bytes on NVIDIA, 1-256 elsewhere), so chunks start at multiples of `quantum` channels and
// each block of output channels is packed with `cin_pad` input channels.
struct UniformSlabChunks {
  int64_t quantum = 1;  // chunk starts are multiples of this many input channels
  int64_t cin_pad = 0;  // input channels per output block in the packing (a multiple of quantum)
  int64_t max = 0;      // input channels one binding holds (a multiple of quantum unless all of them)
  int64_t chunk = 0;    // input channels per dispatch: max, capped by the limit (> 0), a multiple of quantum
};
UniformSlabChunks uniform_slab_chunks(const DeviceInfo& info, int64_t cin, int64_t bytes_per_channel, int64_t limit);

// Whether `bytes` read as texels of `texel_bytes` fit one texel buffer view (maxTexelBufferElements):
// the texel forms of the convs and pads fall back to storage-buffer reads where they do not.
bool texel_view_fits(const DeviceInfo& info, uint64_t bytes, uint64_t texel_bytes);

// A packed weight array on the device in `p` (fp16: rounded to nearest even; an Error names `who` and
// the first value beyond +-65504).
Tensor upload_weights(Context& ctx, const std::vector<float>& values, Precision p, const std::string& who);

// Device round trips of host tensors to f32 or f16 tensors. Uploading to f16 rounds to nearest even
// and throws Error naming the first value beyond fp16's range (+-65504) instead of turning it into Inf.
Tensor to_device(Context& ctx, const HostTensor& host, DType dtype = DType::f32);
void upload(const HostTensor& host, Tensor& t);  // t must have the host tensor's shape
HostTensor to_host(const Tensor& t);             // f32 or f16 tensors

// A channel range [c0, c0+c) and batch range [n0, n0+n) of a tensor; c or n = -1 means "to the end".
// T is `const Tensor` (device: `Slice`) or `const HostTensor` / `HostTensor` (CPU references).
template <class T>
struct SliceOf {
  T* t = nullptr;
  int64_t c0 = 0, c = -1;
  int64_t n0 = 0, n = -1;

  SliceOf() = default;
  SliceOf(T& tensor, int64_t c0_ = 0, int64_t c_ = -1, int64_t n0_ = 0, int64_t n_ = -1)
      : t(&tensor), c0(c0_), c(c_), n0(n0_), n(n_) {}
  SliceOf(T* tensor, int64_t c0_ = 0, int64_t c_ = -1, int64_t n0_ = 0, int64_t n_ = -1)
      : t(tensor), c0(c0_), c(c_), n0(n0_), n(n_) {}
  // A const view of a mutable slice.
  template <class U>
  SliceOf(const SliceOf<U>& o) : t(o.t), c0(o.c0), c(o.c), n0(o.n0), n(o.n) {}

  int64_t channels() const { return c < 0 ? tensor_shape().c - c0 : c; }
  int64_t batch() const { return n < 0 ? tensor_shape().n - n0 : n; }
  int64_t height() const { return tensor_shape().h; }
  int64_t width() const { return tensor_shape().w; }
  // The shape of the view: {batch, channels, h, w}.
  Shape shape() const { return {batch(), channels(), height(), width()}; }
  const Shape& tensor_shape() const {
    if constexpr (requires { t->shape(); }) return t->shape();
    else return t->shape;
  }
  // Element (n, c, y, x) of the view, for host tensors.
  decltype(auto) at(int64_t n_, int64_t c_, int64_t y, int64_t x) const { return t->at(n0 + n_, c0 + c_, y, x); }
};

using Slice = SliceOf<const Tensor>;
using HostSlice = SliceOf<const HostTensor>;
using HostSliceOut = SliceOf<HostTensor>;

// Checks that a slice lies inside its tensor and is f32 or f16; `what` names it in the error.
void check_slice(const Slice& s, const std::string& op, const std::string& what);
// The precision of an f32 / f16 slice.
Precision slice_precision(const Slice& s);
// Throws Error naming `op` and `what` unless the slice's dtype is that of `p`.
void check_precision(const Slice& s, Precision p, const std::string& op, const std::string& what);
void check_slice(const HostSlice& s, const std::string& op, const std::string& what);

// How a slice is bound to a dispatch: a byte range starting at an aligned offset at or before the
// slice's first element, plus the element offset of that first element and the batch stride, which
// the shader adds itself (channel offsets are rarely aligned to the binding alignment).
struct BoundSlice {
  Arg arg;
  uint32_t offset = 0;        // elements from the start of the bound range to element (n0, c0, 0, 0)
  uint32_t batch_stride = 0;  // elements between batch items (C_total * H * W)
};
BoundSlice bind_slice(const Slice& s, Access access);

// How a memory-bound op (reflection_pad, crop, space_to_depth, depth_to_space, the elementwise ops)
// reads its inputs: through uniform texel buffers (its "<shader>_texel" form; on llvmpipe a texel
// fetch is one gather, a storage-buffer load a loop over the lanes) where every bound input fits
// one texel view, or always as storage buffers (texel_fetch = false).
struct TexelReadOptions {
  bool texel_fetch = true;
};
// `shader`, or its texel form with `ins` bound as R32 (R16 in fp16) texels where `opt` asks for it
// and each bound input fits one texel view.
std::string texel_read_shader(const Context& ctx, const std::string& shader, std::initializer_list<BoundSlice*> ins,
                              Precision prec, const TexelReadOptions& opt);

}  // namespace vkunroll
