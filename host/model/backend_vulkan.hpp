// The Vulkan backend: the kernels' GPU ops recorded into one CommandStream per flush. Buffers are
// device Tensors; a released buffer is reused by a later alloc() of the same shape within the same
// recording (the stream's hazard barriers order the reuse) and destroyed at the next flush (also
// forced once kPoolFlushBytes are pooled), so device memory follows the graph's liveness.
#pragma once
#include <map>
#include <memory>
#include <vector>

#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/runtime/command_stream.hpp"

namespace vkunroll {

class Conv2d;
class ConvTranspose2d;
class ConvWorkspace;
class Profiler;

class VulkanBackend final : public Backend {
 public:
  explicit VulkanBackend(Context& ctx, Profiler* profiler = nullptr);
  ~VulkanBackend() override;
  std::string name() const override { return "vulkan"; }
  int alloc(const Shape& shape, const std::string& what) override;
  void release(int buf) override;
  Shape shape(int buf) const override;
  void upload(const BufferSlice& dst, std::span<const float> data) override;
  std::vector<float> download(const BufferSlice& src) override;
  int prepare_conv(const ConvDesc& desc, const WeightTensor& weight, const WeightTensor& bias) override;
  void conv(int conv, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) override;
  void space_to_depth(const BufferSlice& in, const BufferSlice& out) override;
  void depth_to_space(const BufferSlice& in, const BufferSlice& out) override;
  void reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) override;
  void crop(const BufferSlice& in, const BufferSlice& out, int top, int left) override;
  void copy(const BufferSlice& in, const BufferSlice& out) override;
  void add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) override;
  void tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) override;
  void backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) override;
  void hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m, const BufferSlice& out,
                         float forced) override;
  void flush() override;
  uint64_t max_buffer_bytes() const override;
  // Caps max_buffer_bytes() below the device's limit (0: no cap), e.g. to test tiling.
  void set_max_buffer_bytes(uint64_t b) { max_buffer_cap_ = b; }

  Context& context() { return ctx_; }
  // Bytes of device memory held by buffers (live + pooled for reuse), and its peak.
  uint64_t device_bytes() const { return device_bytes_; }
  uint64_t device_peak_bytes() const { return device_peak_; }
  // Bytes of prepared weights on the device (all packings the conv kernels keep).
  uint64_t weight_bytes() const { return weight_bytes_; }

 private:
  struct Buf;
  const Tensor& tensor(int buf) const;
  Context& ctx_;
  std::shared_ptr<ConvWorkspace> workspace_;  // Winograd scratch shared by every conv
  std::unique_ptr<CommandStream> cs_;
  std::vector<std::unique_ptr<Buf>> bufs_;
  std::vector<std::unique_ptr<Conv2d>> convs_;
  std::vector<std::unique_ptr<ConvTranspose2d>> deconvs_;
  std::vector<int> conv_index_;        // conv id -> index in convs_ (>= 0) or ~index in deconvs_
  std::vector<ConvDesc> descs_;
  uint64_t device_bytes_ = 0, device_peak_ = 0, weight_bytes_ = 0, pooled_bytes_ = 0;
  uint64_t max_buffer_cap_ = 0;
};

}  // namespace vkunroll
