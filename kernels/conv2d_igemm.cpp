// conv2d, the GPU family (igemm_l, igemm_m, igemm_s, igemm_n): one tiled implicit-GEMM dispatch per conv
// with bias, activation and residual fused (kernels/igemm.hpp, shaders/conv2d_igemm.comp), the GPU
// choice among the family and the coopmat path, and what each algorithm's tiles imply (cost()).
#include <algorithm>

#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

IgemmTile Conv2d::igemm_tile(ConvAlgo a) {
  switch (a) {
    case ConvAlgo::igemm_l: return {128, 128, 8, 8, 8};
    case ConvAlgo::igemm_m: return {64, 64, 16, 4, 4};
    case ConvAlgo::igemm_s: return {32, 64, 16, 4, 4};
    case ConvAlgo::igemm_n: return {16, 128, 16, 4, 4};
    default: break;
  }
  throw Error(std::string("conv2d: ") + conv_algo_name(a) + " is not an igemm variant");
}

IgemmProblem Conv2d::igemm_problem(const Shape& in) const {
  const Shape os = output_shape(in);
  IgemmProblem pb;
  pb.kh = pb.kw = static_cast<uint32_t>(params_.kernel);
  pb.stride = static_cast<uint32_t>(params_.stride);
  pb.pad = static_cast<uint32_t>(params_.pad);
  pb.cin = cin_;
  pb.cout = cout_;
  pb.in = in;
  pb.out = os;
  pb.gh = os.h;
  pb.gw = os.w;
  pb.act = params_.act;
  pb.precision = precision_;
  return pb;
}

bool Conv2d::igemm_fits_shape(ConvAlgo algo, const Shape& in) const {
  return igemm_fits(ctx_.info(), igemm_tile(algo), igemm_problem(in));
}

ConvAlgo Conv2d::gpu_choice(const Shape& in) const {
  const Shape os = output_shape(in);
  GpuConvFacts f{params_.kernel, params_.stride, cin_, cout_, os.n * os.h * os.w,
                 static_cast<int64_t>(ctx_.info().compute_units), supports(ConvAlgo::coopmat) && supports(ConvAlgo::coopmat, in)};
  return gpu_conv_heuristic(f);
}

void Conv2d::pack_igemm() const {
  if (!weight_igemm_.empty()) return;
  const int64_t kk = static_cast<int64_t>(params_.kernel) * params_.kernel;
  const std::vector<float>& w = weight_host_.data;  // [cout][cin][k][k]
  weight_igemm_ = upload_weights(igemm_pack(1, cin_, kk, cout_, [&](int64_t, int64_t ci, int64_t tap, int64_t co) {
    return w[static_cast<size_t>((co * cin_ + ci) * kk + tap)];
  }));
}

void Conv2d::record_gpu_family(CommandStream& cs, ConvAlgo algo, const IgemmProblem& pb, IgemmBindings b,
                               const DispatchInfo& info) const {
  if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
  IgemmTile tile;
  if (algo == ConvAlgo::coopmat) {
    pack_coopmat();
    tile = coopmat_tile_for_device();
    b.weight = {weight_coopmat_.range(), Access::read};
  } else {
    pack_igemm();
    tile = igemm_tile(algo);
    b.weight = {weight_igemm_.range(), Access::read};
  }
  const uint64_t scratch = std::min<uint64_t>(ctx_.info().max_storage_buffer_range, winograd_scratch_limit_);
  igemm_record(ctx_, cs, *workspace_, tile, pb, b, igemm_splits(ctx_.info(), tile, pb, scratch, igemm_splits_forced_), info);
}

void Conv2d::record_igemm(CommandStream& cs, const Recording& r, ConvAlgo algo) const {
  DispatchInfo info = r.info;
  info.name += std::string("_") + conv_algo_name(algo);
  record_gpu_family(cs, algo, igemm_problem(r.is), {r.in, r.out, r.res, r.has_res, {}, {bias_.range(), Access::read}}, info);
}

ConvCost Conv2d::cost(ConvAlgo algo, const Shape& in) const {
  if (algo == ConvAlgo::automatic) algo = choose_algorithm(in.h, in.w);
  if (is_igemm(algo)) {
    const IgemmTile tile = igemm_tile(algo);
    const IgemmProblem pb = igemm_problem(in);
    const uint64_t scratch = std::min<uint64_t>(ctx_.info().max_storage_buffer_range, winograd_scratch_limit_);
    return igemm_cost(tile, pb, igemm_splits(ctx_.info(), tile, pb, scratch, igemm_splits_forced_));
  }
  // The others keep no tiles in shared memory (coopmat: its fragments' gather, counted as global):
  // each output value reads its whole window and weights once, the lower bound of their traffic.
  const Shape os = output_shape(in);
  const double e = static_cast<double>(elem_bytes()), window = static_cast<double>(cin_) * params_.kernel * params_.kernel;
  ConvCost c;
  c.fma = flop(in) / 2;
  c.global_bytes = e * (static_cast<double>(os.count()) + static_cast<double>(in.count()) +
                        static_cast<double>(cout_) * window);
  return c;
}

}  // namespace vkunroll
