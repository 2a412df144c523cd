// The backend interface the SelfUnroll graph (host/model/model.cpp) is written against, once:
// buffers are NCHW float arrays of the backend, held by a move-only Buffer handle that releases its
// buffer when it goes (so no buffer is released twice or forgotten), and named by an int id in the
// ops; a BufferSlice is a batch range and a channel range of one buffer (same height and width; the
// backend's counterpart of the kernels' Slice of a Tensor), so concatenations are written in place.
// Backends: VulkanBackend (host/model/backend_vulkan.hpp, GPU kernels recorded into a CommandStream)
// and CpuBackend (host/model/backend_cpu.hpp, the kernels' CPU references).
#pragma once
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "vkunroll/base/events.hpp"
#include "vkunroll/base/precision.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"
#include "vkunroll/runtime/tensor.hpp"

namespace vkunroll {

class ConvChoiceTable;

// A view, owning nothing: the buffer must outlive it.
struct BufferSlice {
  int buf = -1;
  int64_t n0 = 0, n = 0;  // batch items [n0, n0 + n)
  int64_t c0 = 0, c = 0;  // channels [c0, c0 + c)
};

class Backend;

// One buffer of a backend, owned: released when the handle is destroyed, reset or assigned over.
// Moved, never copied, so each buffer has one owner and is released once. The backend must outlive
// its handles. An empty handle (default, or moved from) holds no buffer: id() -1.
class Buffer {
 public:
  Buffer() = default;
  Buffer(Buffer&& other) noexcept : backend_(other.backend_), id_(other.id_) { other.forget(); }
  Buffer& operator=(Buffer&& other) noexcept {
    if (this != &other) {
      reset();
      backend_ = other.backend_, id_ = other.id_;
      other.forget();
    }
    return *this;
  }
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;
  ~Buffer() { reset(); }

  // Releases the buffer now (nothing when empty): its memory is reusable by later allocations,
  // after the recorded reads of it (the backend orders the reuse).
  void reset() noexcept;
  int id() const { return id_; }
  explicit operator bool() const { return id_ >= 0; }
  Shape shape() const;
  BufferSlice whole() const;                          // every item and channel
  BufferSlice items(int64_t n0, int64_t n) const;     // items [n0, n0 + n), every channel

 private:
  friend class Backend;
  Buffer(Backend* backend, int id) : backend_(backend), id_(id) {}
  void forget() { backend_ = nullptr, id_ = -1; }
  Backend* backend_ = nullptr;
  int id_ = -1;
};

// One convolution layer of the network, prepared (weights uploaded / re-laid) once.
struct ConvDesc {
  std::string name;          // checkpoint prefix, e.g. "flownet.down_path.2.down.0"
  int cin = 0, cout = 0, k = 3, stride = 1, pad = 1;
  bool transposed = false;   // ConvTranspose2d (weight [cin, cout, k, k])
  bool leaky = false;        // LeakyReLU after the conv
  float slope = 0.f;
};

class Backend {
 public:
  virtual ~Backend() = default;
  virtual std::string name() const = 0;
  // The storage precision of the backend's buffers and prepared weights (fp32 unless constructed
  // otherwise); host data is f32 either way.
  virtual Precision precision() const { return Precision::fp32; }

  // Buffers, released by their handle (Buffer::reset or its destructor): the memory is then
  // reusable by later alloc() calls (the backend keeps ordering: a buffer is not overwritten before
  // recorded reads of it have run). `what` names the buffer in errors.
  Buffer alloc(const Shape& shape, const std::string& what) { return Buffer(this, alloc_id(shape, what)); }
  virtual Shape shape(int buf) const = 0;
  Shape slice_shape(const BufferSlice& v) const;  // the view's items and channels at its buffer's extent
  // Host data in NCHW order with the slice's extent. Both are ordered with the recorded work:
  // upload() copies `data` before returning (no wait); download() fills `dst` by the next flush().
  virtual void upload(const BufferSlice& dst, std::span<const float> data) = 0;
  virtual void download(const BufferSlice& src, std::span<float> dst) = 0;
  // download() and flush(): the slice's values now.
  std::vector<float> download(const BufferSlice& src);

  virtual int prepare_conv(const ConvDesc& desc, const WeightTensor& weight, const WeightTensor& bias) = 0;
  // out = act(conv(in)) (+ residual, only for convs without activation). Views of equal batch.
  virtual void conv(int conv, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) = 0;
  // Between these, convs read growing channel prefixes of one buffer (a dense block) of at most
  // `channels` channels, unchanged in between: a backend may keep what it derived from the
  // channels it has seen (Vulkan: Winograd's transformed input). end_dense_block before any write
  // to the channels read so far.
  virtual void begin_dense_block(int64_t channels) { (void)channels; }
  virtual void end_dense_block() {}

  // out = conv `conv` (prepared from `desc`, not transposed) with its input and output folded
  // (ConvFold, kernels/conv2d.hpp): the input is `pieces` concatenated along the channels, read as
  // they are, reflection-padded, space-to-depth or depth-to-space; out is the conv's output from
  // (crop_top, crop_left), optionally tanh_scale x tanh. One dispatch where the backend folds them
  // into the conv (Vulkan with the GPU family); otherwise the separate ops, through buffers of their
  // own (the same values).
  void conv_folded(int conv, const ConvDesc& desc, const std::vector<BufferSlice>& pieces, const ConvFold& fold,
                   const BufferSlice& out);

  virtual void space_to_depth(const BufferSlice& in, const BufferSlice& out) = 0;   // PixelUnshuffle(2)
  virtual void depth_to_space(const BufferSlice& in, const BufferSlice& out) = 0;   // PixelShuffle(2)
  // out (larger) = reflection padding of in, in placed at (top, left).
  virtual void reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) = 0;
  // out (smaller) = in[top : top + H_out, left : left + W_out].
  virtual void crop(const BufferSlice& in, const BufferSlice& out, int top, int left) = 0;
  virtual void copy(const BufferSlice& in, const BufferSlice& out) = 0;
  virtual void add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) = 0;
  virtual void clamp01(const BufferSlice& in, const BufferSlice& out) = 0;  // out = clamp(in, 0, 1)
  virtual void tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) = 0;  // out = scale * tanh(in)
  virtual void backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) = 0;
  // out[.., dst_y + i, dst_x + j] = in[.., src.y + i, src.x + j] (tiles cut and stitched in place).
  virtual void copy_rect(const BufferSlice& in, const BufferSlice& out, const Rect& src, int64_t dst_y, int64_t dst_x) = 0;
  virtual void fill_rect(const BufferSlice& out, const Rect& rect, float value) = 0;

  // Event tensors ev1, ev2, ev3 of `pairs` from the events: one buffer [3P, 2N, h, w] (ev1 is items
  // [0, P), ev2 [P, 2P), ev3 [2P, 3P)) to read only. It stays valid until the next event_tensors()
  // call, which may reuse its memory (the backend orders the reuse); a handle still held then names
  // a buffer that is gone (ops on it throw Error).
  Buffer event_tensors(const EventStream& events, const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec) {
    return Buffer(this, event_tensors_id(events, pairs, spec));
  }
  // The weight-free physics unroller for one target: out from rs, one whole item [1, C, H, W] each
  // (out may be an item of a batch, written in place).
  virtual void physics_unroll(const BufferSlice& rs, const PixelEventLists& lists, const PhysicsUnrollParams& params,
                              const BufferSlice& out) = 0;
  // m = hardsigmoid(score) (or `forced` when >= 0); out = m * a + (1 - m) * b.
  virtual void hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m,
                                 const BufferSlice& out, float forced) = 0;

  // Runs everything recorded so far and waits (a no-op for eager backends).
  virtual void flush() = 0;
  // The stage the next recorded ops belong to (the Vulkan backend sums their GPU timestamps per
  // stage: DeviceTraffic::gpu_ms_by_stage). Ops run at once on the CPU backend: nothing to tag.
  virtual void set_stage(const std::string& stage) { (void)stage; }
  // The largest tensor one buffer may hold (bytes); the graph splits batches to respect it.
  virtual uint64_t max_buffer_bytes() const = 0;

  // What a device backend reports beyond its ops (the CPU backend: nothing). Submissions it made
  // because released buffers held too much memory (a wait inside the work), and the peak of device
  // memory its buffers held (live and pooled).
  virtual uint64_t pool_flushes() const { return 0; }
  virtual uint64_t device_peak_bytes() const { return 0; }
  // The measured conv algorithm choice (host/model/conv_choice.hpp): its table (null: the kernels'
  // heuristic decides), the conv shapes this backend timed, and the recorded convs that took the
  // table's algorithm.
  virtual const ConvChoiceTable* conv_table() const { return nullptr; }
  virtual uint64_t convs_timed() const { return 0; }
  virtual uint64_t convs_from_table() const { return 0; }
  // Conv calls recorded per algorithm name (transposed convs as "transposed NAME"); empty: not counted.
  virtual std::map<std::string, uint64_t> conv_calls_by_algorithm() const { return {}; }

  // Memory accounting of live buffers (bytes), maintained by alloc() and the handles' release.
  uint64_t live_bytes() const { return live_bytes_; }
  uint64_t peak_bytes() const { return peak_bytes_; }
  void reset_peak() { peak_bytes_ = live_bytes_; }

 protected:
  // What the backends implement: a new buffer's id, its release (only ever by its handle, once:
  // bookkeeping that cannot fail; any submission it calls for waits for the next alloc), and the
  // event tensors' buffer.
  virtual int alloc_id(const Shape& shape, const std::string& what) = 0;
  virtual void release_id(int buf) noexcept = 0;
  virtual int event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                               const EventTensorSpec& spec) = 0;
  // conv_folded in one dispatch; false where this backend does not fold this conv (it then composes).
  // `in`: the conv's input as the fold makes it (ConvFold::conv_input of the pieces).
  virtual bool conv_folded_at_once(int conv, const std::vector<BufferSlice>& pieces, const Shape& in, const ConvFold& fold,
                                   const BufferSlice& out) {
    (void)conv, (void)pieces, (void)in, (void)fold, (void)out;
    return false;
  }
  void account_alloc(uint64_t b) {
    live_bytes_ += b;
    if (live_bytes_ > peak_bytes_) peak_bytes_ = live_bytes_;
  }
  void account_release(uint64_t b) { live_bytes_ -= b; }

 private:
  friend class Buffer;
  uint64_t live_bytes_ = 0, peak_bytes_ = 0;
};

inline void Buffer::reset() noexcept {
  if (backend_) backend_->release_id(id_);
  forget();
}
inline Shape Buffer::shape() const { return backend_->shape(id_); }
inline BufferSlice Buffer::whole() const {
  const Shape s = shape();
  return {id_, 0, s.n, 0, s.c};
}
inline BufferSlice Buffer::items(int64_t n0, int64_t n) const { return {id_, n0, n, 0, shape().c}; }

// Released device buffers wait in a pool (reusable by an allocation of the same size) until the
// recorded work that may still read them has run; when an allocation finds more than this many
// bytes pooled, the backend first submits and frees them (a wait inside the work, counted), so
// device memory stays near the live bytes.
// The default holds the pool of a whole SelfUnroll frame at the DAVIS346 size (tests/test_session.cpp).
constexpr uint64_t kPoolFlushBytes = 256ull << 20;

// A backend that computes nothing and only tracks buffers: the memory plan of a run.
class PlanningBackend final : public Backend {
 public:
  std::string name() const override { return "plan"; }
  Shape shape(int buf) const override;
  void upload(const BufferSlice&, std::span<const float>) override {}
  void download(const BufferSlice&, std::span<float>) override {}
  using Backend::download;
  int prepare_conv(const ConvDesc&, const WeightTensor&, const WeightTensor&) override { return 0; }
  void conv(int, const BufferSlice&, const BufferSlice&, const BufferSlice*) override {}
  void space_to_depth(const BufferSlice&, const BufferSlice&) override {}
  void depth_to_space(const BufferSlice&, const BufferSlice&) override {}
  void reflect_pad(const BufferSlice&, const BufferSlice&, int, int) override {}
  void crop(const BufferSlice&, const BufferSlice&, int, int) override {}
  void copy(const BufferSlice&, const BufferSlice&) override {}
  void add(const BufferSlice&, const BufferSlice&, const BufferSlice&) override {}
  void clamp01(const BufferSlice&, const BufferSlice&) override {}
  void tanh_scale(const BufferSlice&, const BufferSlice&, float) override {}
  void backward_warp(const BufferSlice&, const BufferSlice&, const BufferSlice&) override {}
  void copy_rect(const BufferSlice&, const BufferSlice&, const Rect&, int64_t, int64_t) override {}
  void fill_rect(const BufferSlice&, const Rect&, float) override {}
  void physics_unroll(const BufferSlice&, const PixelEventLists&, const PhysicsUnrollParams&, const BufferSlice&) override {}
  void hardsigmoid_blend(const BufferSlice&, const BufferSlice&, const BufferSlice&, const BufferSlice&, const BufferSlice&, float) override {}
  void flush() override;
  uint64_t max_buffer_bytes() const override { return max_buffer_bytes_; }
  void set_max_buffer_bytes(uint64_t b) { max_buffer_bytes_ = b; }
  void set_pool_flush_bytes(uint64_t b) { pool_flush_bytes_ = b; }  // as VulkanBackend's
  // Device memory under VulkanBackend's policy (released buffers stay allocated until the next
  // flush unless an allocation of the same size reuses them): its peak.
  uint64_t device_peak_bytes() const override { return device_peak_; }
  // The largest single buffer allocated, with its description.
  uint64_t largest_buffer() const { return largest_; }
  // The live buffers at the peak, largest first ("name shape, ...").
  const std::string& peak_buffers() const { return peak_buffers_; }
  const std::string& largest_buffer_name() const { return largest_name_; }

 private:
  int alloc_id(const Shape& shape, const std::string& what) override;
  void release_id(int buf) noexcept override;
  int event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec) override;
  std::vector<Shape> shapes_;
  std::vector<std::string> names_;
  std::vector<bool> live_;
  std::string peak_buffers_;
  std::vector<Shape> pooled_;
  uint64_t pooled_bytes_ = 0, device_bytes_ = 0, device_peak_ = 0;
  uint64_t max_buffer_bytes_ = 128ull << 20;
  uint64_t pool_flush_bytes_ = kPoolFlushBytes;
  uint64_t largest_ = 0;
  std::string largest_name_;
};

}  // namespace vkunroll
