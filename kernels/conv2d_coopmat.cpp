// conv2d, the `coopmat` path (fp16): the GPU family's implicit GEMM on cooperative matrices (tensor
// cores; fp16 operands, fp32 accumulators), shaders/conv2d_igemm_coopmat.comp: any kernel, stride and
// padding, both operands staged in shared memory, bias, activation and residual fused, one dispatch
// (split-K adds the family's reduce). The weights are A [cout_pad][kpad] row-major (16-byte loads).
// The real shader needs VK_NV_cooperative_matrix with a 16 x {8,16} x {8,16} fp16 -> fp32 subgroup
// shape and subgroups of 32, which its pipeline requires (subgroup size control, full subgroups); its
// emulated form, the same tiling in plain GLSL, runs anywhere (tests: set_coopmat_emulation).
#include <algorithm>

#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {
constexpr uint32_t kWarp = 32;  // invocations per warp: NVIDIA's subgroup size (the real form requires it)
constexpr int64_t kPad = 16;    // cout padding (every supported fragment side divides it)

int64_t round_up(int64_t v, int64_t m) { return (v + m - 1) / m * m; }
}  // namespace

void Conv2d::set_coopmat_emulation(bool on, uint32_t n, uint32_t k) {
  if ((n != 8 && n != 16) || (k != 8 && k != 16))
    throw Error(name_ + ": coopmat emulation fragments 16x" + std::to_string(n) + "x" + std::to_string(k) +
                ", expected n and k of 8 or 16");
  coopmat_emulated_ = on;
  coopmat_emulated_n_ = n;
  coopmat_emulated_k_ = k;
}

bool Conv2d::coopmat_applies() const {
  if (precision_ != Precision::fp16) return false;
  if (coopmat_emulated_) return true;
  return ctx_.info().coopmat_fp16_shape().has_value() && ctx_.info().subgroup_width_refusal(kWarp).empty();
}

IgemmTile Conv2d::coopmat_tile_for_device() const {
  if (coopmat_emulated_) return coopmat_tile(16, coopmat_emulated_n_, coopmat_emulated_k_, true);
  const CoopMatShape s = *ctx_.info().coopmat_fp16_shape();
  return coopmat_tile(s.m, s.n, s.k, false);
}

bool Conv2d::coopmat_fits(const Shape& in) const {
  return coopmat_applies() && igemm_fits(ctx_.info(), coopmat_tile_for_device(), igemm_problem(in));
}

void Conv2d::pack_coopmat() const {
  if (!weight_coopmat_.empty()) return;
  // A = W row-major [cout_pad][kpad], the family's tap-major rows (igemm.hpp), zeros in the padding.
  const int64_t kk = static_cast<int64_t>(params_.kernel) * params_.kernel;
  const std::vector<float>& w = weight_host_.data;  // [cout][cin][k][k]
  weight_coopmat_ = upload_weights(igemm_pack_rows(cin_, kk, cout_, round_up(cout_, kPad),  // fp16 (coopmat is fp16 only)
                                                   [&](int64_t, int64_t ci, int64_t tap, int64_t co) {
                                                     return w[static_cast<size_t>((co * cin_ + ci) * kk + tap)];
                                                   }));
}

void Conv2d::record_coopmat(CommandStream& cs, const Recording& r) const {
  DispatchInfo info = r.info;
  info.name += "_coopmat";
  record_gpu_family(cs, ConvAlgo::coopmat, igemm_problem(r.is),
                    {r.in, r.out, r.res, r.has_res, {}, {bias_.range(), Access::read}}, info);
}

}  // namespace vkunroll
