// The CPU reference backend: every op of the graph on host memory, in fp32, eagerly.
#pragma once
#include <memory>

#include "host/backend.hpp"

namespace vkunroll {

class CpuBackend final : public Backend {
 public:
  CpuBackend();
  ~CpuBackend() override;
  std::string name() const override { return "cpu"; }
  int alloc(const Shape& shape, const std::string& what) override;
  void release(int buf) override;
  Shape shape(int buf) const override;
  void upload(const View& dst, std::span<const float> data) override;
  std::vector<float> download(const View& src) override;
  int prepare_conv(const ConvDesc& desc, const WeightTensor& weight, const WeightTensor& bias) override;
  void conv(int conv, const View& in, const View& out, const View* residual) override;
  void space_to_depth(const View& in, const View& out) override;
  void depth_to_space(const View& in, const View& out) override;
  void reflect_pad(const View& in, const View& out, int top, int left) override;
  void crop(const View& in, const View& out, int top, int left) override;
  void copy(const View& in, const View& out) override;
  void add(const View& a, const View& b, const View& out) override;
  void tanh_scale(const View& in, const View& out, float scale) override;
  void backward_warp(const View& img, const View& flow, const View& out) override;
  void hardsigmoid_blend(const View& score, const View& a, const View& b, const View& m, const View& out,
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
