// The CPU reference backend: every op of the graph on host memory, in fp32, eagerly. Convolutions
// run their output-channel parts on OpenCV's thread pool (cv::parallel_for_), `threads` at a time.
#pragma once
#include <memory>

#include "vkunroll/host/model/backend.hpp"

namespace vkunroll {

class CpuBackend final : public Backend {
 public:
  // threads: convolution parts run in parallel (0: the machine's cores, at most 8).
  explicit CpuBackend(unsigned threads = 0);
  ~CpuBackend() override;
  std::string name() const override { return "cpu"; }
  Shape shape(int buf) const override;
  void upload(const BufferSlice& dst, std::span<const float> data) override;
  void download(const BufferSlice& src, std::span<float> dst) override;
  using Backend::download;
  int prepare_conv(const ConvDesc& desc, const WeightTensor& weight, const WeightTensor& bias) override;
  void conv(int conv, const BufferSlice& in, const BufferSlice& out, const BufferSlice* residual) override;
  void space_to_depth(const BufferSlice& in, const BufferSlice& out) override;
  void depth_to_space(const BufferSlice& in, const BufferSlice& out) override;
  void reflect_pad(const BufferSlice& in, const BufferSlice& out, int top, int left) override;
  void crop(const BufferSlice& in, const BufferSlice& out, int top, int left) override;
  void copy(const BufferSlice& in, const BufferSlice& out) override;
  void add(const BufferSlice& a, const BufferSlice& b, const BufferSlice& out) override;
  void clamp01(const BufferSlice& in, const BufferSlice& out) override;
  void tanh_scale(const BufferSlice& in, const BufferSlice& out, float scale) override;
  void backward_warp(const BufferSlice& img, const BufferSlice& flow, const BufferSlice& out) override;
  void copy_rect(const BufferSlice& in, const BufferSlice& out, const Rect& src, int64_t dst_y, int64_t dst_x) override;
  void fill_rect(const BufferSlice& out, const Rect& rect, float value) override;
  void physics_unroll(const BufferSlice& rs, const PixelEventLists& lists, const PhysicsUnrollParams& params,
                      const BufferSlice& out) override;
  void hardsigmoid_blend(const BufferSlice& score, const BufferSlice& a, const BufferSlice& b, const BufferSlice& m, const BufferSlice& out,
                         float forced) override;
  void flush() override {}
  uint64_t max_buffer_bytes() const override { return max_buffer_bytes_; }
  void set_max_buffer_bytes(uint64_t b) { max_buffer_bytes_ = b; }

 private:
  int alloc_id(const Shape& shape, const std::string& what) override;
  void release_id(int buf) noexcept override;
  int event_tensors_id(const EventStream& events, const std::vector<EventTensorPair>& pairs, const EventTensorSpec& spec) override;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  uint64_t max_buffer_bytes_ = 1ull << 34;
};

}  // namespace vkunroll
