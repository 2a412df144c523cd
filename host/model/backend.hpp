// The backend interface the SelfUnroll graph (host/model/model.cpp) is written against, once:
// buffers are NCHW float arrays owned by the backend, named by an int id; a BufferSlice is a batch
// range and a channel range of one buffer (same height and width; the backend's counterpart of the
// kernels' Slice of a Tensor), so concatenations are written in place.
// Backends: VulkanBackend (host/model/backend_vulkan.hpp, GPU kernels recorded into a CommandStream)
// and CpuBackend (host/model/backend_cpu.hpp, the kernels' CPU references).
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/tensor.hpp"

namespace vkunroll {

struct BufferSlice {
  int buf = -1;
  int64_t n0 = 0, n = 0;  // batch items [n0, n0 + n)
  int64_t c0 = 0, c = 0;  // channels [c0, c0 + c)
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

  // Buffers. release() makes the memory reusable by later alloc() calls (the backend keeps
  // ordering: a buffer is not overwritten before recorded reads of it have run).
  virtual int alloc(const Shape& shape, const std::string& what) = 0;
  virtual void release(int buf) = 0;
  virtual Shape shape(int buf) const = 0;
  // Host data in NCHW order with the view's extent.
  virtual void upload(const BufferSlice& dst, std::span<const float> data) = 0;
  virtual std::vector<float> download(const BufferSlice& src) = 0;

  virtual int prepare_conv(const ConvDesc& desc, const WeightTensor& weight, const WeightTensor& bias) = 0;
  // out = act(conv(in)) (+ residual, only for convs without activation). Views of equal batch.
  virtual void conv(int conv, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) = 0;

  virtual void space_to_depth(const BufferSlice& in, const BufferSlice& out) = 0;   // PixelUnshuffle(2)
  virtual void depth_to_space(const BufferSlice& in, const BufferSlice& out) = 0;   // PixelShuffle(2)
  // out (larger) = reflection padding of in, in placed at (top, left).
  virtual void reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) = 0;
  // out (smaller) = in[top : top + H_out, left : left + W_out].
  virtual void crop(const BufferSlice& in, const BufferSlice& out, int top, int left) = 0;
  virtual void copy(const BufferSlice& in, const BufferSlice& out) = 0;
  virtual void add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) = 0;
  virtual void tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) = 0;  // out = scale * tanh(in)
  virtual void backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) = 0;
  // m = hardsigmoid(score) (or `forced` when >= 0); out = m * a + (1 - m) * b.
  virtual void hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m,
                                 const BufferSlice& out, float forced) = 0;

  // Runs everything recorded so far and waits (a no-op for eager backends).
  virtual void flush() = 0;
  // The largest tensor one buffer may hold (bytes); the graph splits batches to respect it.
  virtual uint64_t max_buffer_bytes() const = 0;

  // Memory accounting of live buffers (bytes), maintained by alloc()/release().
  uint64_t live_bytes() const { return live_bytes_; }
  uint64_t peak_bytes() const { return peak_bytes_; }
  void reset_peak() { peak_bytes_ = live_bytes_; }

 protected:
  void account_alloc(uint64_t b) {
    live_bytes_ += b;
    if (live_bytes_ > peak_bytes_) peak_bytes_ = live_bytes_;
  }
  void account_release(uint64_t b) { live_bytes_ -= b; }

 private:
  uint64_t live_bytes_ = 0, peak_bytes_ = 0;
};

// Released device buffers wait in a pool (reusable by an allocation of the same shape) until the
// recorded work that may still read them has run; past this many pooled bytes the backend
// submits and frees them, so device memory stays close to the live bytes.
constexpr uint64_t kPoolFlushBytes = 32ull << 20;

// A backend that computes nothing and only tracks buffers: the memory plan of a run.
class PlanningBackend final : public Backend {
 public:
  std::string name() const override { return "plan"; }
  int alloc(const Shape& shape, const std::string& what) override;
  void release(int buf) override;
  Shape shape(int buf) const override;
  void upload(const BufferSlice&, std::span<const float>) override {}
  std::vector<float> download(const BufferSlice& src) override;
  int prepare_conv(const ConvDesc&, const WeightTensor&, const WeightTensor&) override { return 0; }
  void conv(int, const BufferSlice&, const BufferSlice&, const BufferSlice*) override {}
  void space_to_depth(const BufferSlice&, const BufferSlice&) override {}
  void depth_to_space(const BufferSlice&, const BufferSlice&) override {}
  void reflect_pad(const BufferSlice&, const BufferSlice&, int, int) override {}
  void crop(const BufferSlice&, const BufferSlice&, int, int) override {}
  void copy(const BufferSlice&, const BufferSlice&) override {}
  void add(const BufferSlice&, const BufferSlice&, const BufferSlice&) override {}
  void tanh_scale(const BufferSlice&, const BufferSlice&, float) override {}
  void backward_warp(const BufferSlice&, const BufferSlice&, const BufferSlice&) override {}
  void hardsigmoid_blend(const BufferSlice&, const BufferSlice&, const BufferSlice&, const BufferSlice&, const BufferSlice&, float) override {}
  void flush() override;
  uint64_t max_buffer_bytes() const override { return max_buffer_bytes_; }
  void set_max_buffer_bytes(uint64_t b) { max_buffer_bytes_ = b; }
  // Device memory under VulkanBackend's policy (released buffers stay allocated until the next
  // flush unless an allocation of the same shape reuses them): its peak.
  uint64_t device_peak_bytes() const { return device_peak_; }
  // The largest single buffer allocated, with its description.
  uint64_t largest_buffer() const { return largest_; }
  // The live buffers at the peak, largest first ("name shape, ...").
  const std::string& peak_buffers() const { return peak_buffers_; }
  const std::string& largest_buffer_name() const { return largest_name_; }

 private:
  std::vector<Shape> shapes_;
  std::vector<std::string> names_;
  std::vector<bool> live_;
  std::string peak_buffers_;
  std::vector<Shape> pooled_;
  uint64_t pooled_bytes_ = 0, device_bytes_ = 0, device_peak_ = 0;
  uint64_t max_buffer_bytes_ = 128ull << 20;
  uint64_t largest_ = 0;
  std::string largest_name_;
};

}  // namespace vkunroll
