// conv_transpose2d: PyTorch's ConvTranspose2d (weight [in, out, kh, kw]) with bias and a fused
// activation; the UNets use kernel 4, stride 2, padding 1 (output exactly 2H x 2W).
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv_options.hpp"
#include "vkunroll/kernels/igemm.hpp"

namespace vkunroll {

struct ConvTranspose2dParams {
  int kernel = 4, stride = 2, pad = 1;
  Act act;
};

enum class ConvTransposeAlgo : uint32_t {
  automatic = 0,
  naive = 1,    // one invocation per output value, loops over the taps that hit it
  blocked = 2,  // sub-pixel (phase) decomposition, 4 pixels x 8 output channels per invocation
  direct = 3,   // the same decomposition, 8 pixels x 16 output channels per invocation, weights from a
                // uniform buffer, one dispatch per channel block and input-channel chunk
  igemm = 4,    // the GPU family (kernels/igemm.hpp): the STRIDE^2 phases as stride-1 convs of the
                // (kernel / stride)^2 sub-kernels, one tiled implicit-GEMM dispatch; kernel % stride == 0
};
const char* conv_transpose_algo_name(ConvTransposeAlgo a);

// Output extent along one axis: (in - 1) * stride - 2 pad + kernel.
int64_t conv_transpose_output_size(int64_t in, int kernel, int stride, int pad);

// CPU reference, double accumulation. weight [cin, cout, k, k]; bias count cout or empty.
void conv_transpose2d_ref(HostSlice in, HostSliceOut out, const HostTensor& weight, const HostTensor& bias,
                          const ConvTranspose2dParams& params);

class ConvTranspose2d {
 public:
  // `options`: precision (fp16: f16 weights, input and output) and tuning knobs, validated here (of
  // the knobs only direct_cob applies to transposed convs).
  ConvTranspose2d(Context& ctx, const HostTensor& weight, const HostTensor& bias,
                  const ConvTranspose2dParams& params = {}, std::string name = "conv_transpose2d",
                  const ConvOptions& options = {});

  // in and out have the conv's precision (f32 or f16 tensors).
  void record(CommandStream& cs, Slice in, Slice out, ConvTransposeAlgo algo = ConvTransposeAlgo::automatic) const;

  bool supports(ConvTransposeAlgo algo) const;
  // Every algorithm record() accepts, naive left out: the candidates a measured choice times.
  std::vector<ConvTransposeAlgo> candidates() const;
  ConvTransposeAlgo choose_algorithm(int64_t h, int64_t w) const;
  // `automatic` takes the GPU family (igemm) on any device, lavapipe included (the default on GPUs).
  void set_gpu_family(bool on) { gpu_family_ = on; }
  ConvTransposeAlgo gpu_choice() const;  // the GPU family's choice: igemm where it applies, else blocked
  void set_igemm_splits(int n) { igemm_splits_forced_ = n; }  // 0: per device and shape (tests force n)
  ConvCost cost(ConvTransposeAlgo algo, const Shape& in) const;
  Shape output_shape(const Shape& in) const;
  double flop(const Shape& in) const;  // 2 x multiply-adds: in.count/cin x cin x cout x k x k
  int64_t cin() const { return cin_; }
  int64_t cout() const { return cout_; }
  const ConvTranspose2dParams& params() const { return params_; }
  Precision precision() const { return precision_; }
  // Caps the input channels per dispatch of the direct path (chunks accumulate in the output). Tests.
  void set_direct_chunk_limit(int64_t channels) { direct_chunk_limit_ = channels; }
  // direct reads its input through a uniform texel buffer (faster on lavapipe) where the bound
  // input fits maxTexelBufferElements; false forces the storage-buffer variant (tests).
  void set_texel_fetch(bool on) { texel_fetch_ = on; }

 private:
  Context& ctx_;
  std::string name_;
  ConvTranspose2dParams params_;
  Precision precision_ = Precision::fp32;
  int64_t cin_ = 0, cout_ = 0;
  Tensor weight_;          // [cin][cout][k][k] as given
  Tensor bias_;            // [cout], always f32
  Tensor weight_blocked_;  // [ceil(cout/8)][cin][k*k][8]
  Tensor bias_blocked_;    // [ceil(cout/8)*8], f32
  void pack_direct() const;
  UniformSlabChunks direct_chunks() const;  // input-channel chunks of the uniform weight slabs
  HostTensor weight_host_;         // as given, for the lazily uploaded direct packing
  mutable Tensor weight_direct_;   // [ceil(cout/COB)][cin (+ one chunk)][16][COB]
  int64_t direct_cob_ = 16;
  int64_t direct_chunk_limit_ = 0;
  bool texel_fetch_ = true;
  bool gpu_family_ = false;
  int igemm_splits_forced_ = 0;
  mutable Tensor weight_igemm_;  // A of each phase: [stride^2][kpad][cout_pad] (kernels/igemm.hpp)
  mutable std::shared_ptr<ConvWorkspace> workspace_;  // split-K's partial sums
  IgemmProblem igemm_problem(const Shape& in) const;
  IgemmTile igemm_tile() const;
  void record_igemm(CommandStream& cs, const BoundSlice& in, const BoundSlice& out, const Shape& is,
                    const DispatchInfo& info) const;
};

}  // namespace vkunroll
