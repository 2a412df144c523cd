// The CPU reference backend: every op of the graph on host memory, in fp32, eagerly.
#pragma once
#include <memory>

#include "vkunroll/host/model/backend.hpp"

namespace vkunroll {

class CpuBackend final : public Backend {
 public:
  CpuBackend();
  ~CpuBackend() override;
  std::string name() const override { return "cpu"; }
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
  void flush() override {}
  uint64_t max_buffer_bytes() const override { return max_buffer_bytes_; }
  void set_max_buffer_bytes(uint64_t b) { max_buffer_bytes_ = b; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  uint64_t max_buffer_bytes_ = 1ull << 34;
};

}  // namespace vkunroll
