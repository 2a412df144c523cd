// conv2d, the `coopmat` path (fp16): a GEMM on cooperative matrices (fp16 operands, fp32
// accumulators) into M, then conv1x1_output (bias, activation, residual). 1x1 stride 1: conv1x1_pack
// copies the input into V [cin][pixels], shaders/conv1x1_coopmat.comp multiplies (in input-channel
// chunks that fit the scratch). 3x3 and 5x5 stride 1, pad k/2: shaders/conv_kxk_coopmat.comp, an
// implicit GEMM (the input gathered into shared memory per step, no scratch). Every GEMM dimension is
// padded to whole fragments: output channels to 16 (W's zero rows), the reduction (cin, or cin x k x k) to 16 (W's
// zero columns; V's zero rows: conv1x1_pack's c_valid), pixels to the workgroup's NW x 32 (zeros).
// The real shaders need VK_NV_cooperative_matrix with a 16 x {8,16} x {8,16} fp16 -> fp32 subgroup
// shape and subgroups of 32 (NVIDIA); their emulated form, the same tiling in plain GLSL, runs
// anywhere (tests: set_coopmat_emulation).
#include <algorithm>

#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
constexpr uint32_t kWarp = 32;      // invocations per warp: NVIDIA's subgroup size (the real form needs it)
constexpr uint32_t kWarps = 4;      // warps per workgroup, side by side along the pixels
constexpr uint32_t kWarpPixels = 32;  // pixels per warp: FN = 32 / lN fragments
constexpr int64_t kPad = 16;        // cin and cout padding (every supported fragment side divides it)

int64_t round_up(int64_t v, int64_t m) { return (v + m - 1) / m * m; }

struct CoopmatTiling {
  uint32_t m = 16, n = 8, k = 16;  // fragment (lM x lN x lK)
  uint32_t fm = 1, fn = 4;         // fragments per warp along channels and pixels
  bool emulated = false;
};

// Fragments per warp along the output channels: the largest of 4, 3, 2, 1 that divides cout's
// 16-channel blocks (no padding beyond 16; 96 -> 3, 64 -> 4, 48 -> 3, 80 -> 1).
uint32_t coopmat_fm(int64_t cout) {
  const int64_t blocks = round_up(cout, kPad) / kPad;
  for (uint32_t f = 4; f > 1; --f)
    if (blocks % f == 0) return f;
  return 1;
}

int64_t coopmat_pix_pad(const Shape& in) { return round_up(in.n * in.h * in.w, kWarps * kWarpPixels); }
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
  const Conv2dParams& q = params_;
  // 5x5: SFENet1 (396->96) is the largest conv of the model; cuDNN runs it on tensor cores (H200, 2026-12-04).
  const bool shape = q.stride == 1 && (q.kernel == 1 || q.kernel == 3 || q.kernel == 5) && q.pad == q.kernel / 2;
  if (!shape || precision_ != Precision::fp16) return false;
  if (coopmat_emulated_) return true;
  return ctx_.info().coopmat_fp16_shape().has_value() && ctx_.info().subgroup_size == kWarp;
}

int64_t Conv2d::coopmat_chunk(const Shape& in) const {
  // V (fp16, [chunk][pix_pad]) must fit the scratch limit and one binding; whole 16-channel fragments.
  const uint64_t limit = std::min<uint64_t>(ctx_.info().max_storage_buffer_range, winograd_scratch_limit_);
  const uint64_t per_channel = static_cast<uint64_t>(coopmat_pix_pad(in)) * 2;
  const int64_t rows = static_cast<int64_t>(limit / per_channel) / kPad * kPad;
  return std::min<int64_t>(round_up(cin_, kPad), rows);
}

bool Conv2d::coopmat_fits(const Shape& in) const {
  const int64_t cout_pad = round_up(cout_, kPad), pix_pad = coopmat_pix_pad(in);
  const uint64_t m_bytes = static_cast<uint64_t>(cout_pad * pix_pad) * 4;  // M: fp32, every output channel
  const bool chunks = params_.kernel > 1 || coopmat_chunk(in) >= kPad;   // k x k: no V scratch (im2col in shared)
  return m_bytes <= ctx_.info().max_storage_buffer_range && chunks &&
         static_cast<uint64_t>(pix_pad / (kWarps * kWarpPixels)) <= ctx_.info().max_workgroup_count[0];
}

void Conv2d::pack_coopmat() const {
  if (!weight_coopmat_.empty()) return;
  // A = W row-major [cout_pad][kpad], kk = ci*k*k + ky*k + kx (the given layout's), zeros in the padding.
  const int64_t kdim = cin_ * params_.kernel * params_.kernel;
  const int64_t cout_pad = round_up(cout_, kPad), kpad = round_up(kdim, kPad);
  std::vector<float> a(static_cast<size_t>(cout_pad * kpad), 0.f);
  for (int64_t co = 0; co < cout_; ++co)
    for (int64_t kk = 0; kk < kdim; ++kk)
      a[static_cast<size_t>(co * kpad + kk)] = weight_host_.data[static_cast<size_t>(co * kdim + kk)];
  weight_coopmat_ = upload_weights(a);  // fp16 (coopmat is fp16 only)
}

void Conv2d::record_coopmat(CommandStream& cs, const Recording& r) const {
  if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
  pack_coopmat();
  const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
  CoopmatTiling t;
  if (coopmat_emulated_) {
    t.n = coopmat_emulated_n_, t.k = coopmat_emulated_k_, t.emulated = true;
  } else {
    const CoopMatShape s = *ctx_.info().coopmat_fp16_shape();
    t.m = s.m, t.n = s.n, t.k = s.k;
  }
  t.fm = coopmat_fm(cout_);
  t.fn = kWarpPixels / t.n;
  const bool implicit = params_.kernel > 1;  // the implicit GEMM (3x3 or 5x5); 1x1: pack + GEMM
  const int64_t cout_pad = round_up(cout_, kPad), kpad = round_up(cin_ * params_.kernel * params_.kernel, kPad);
  const int64_t pix_pad = coopmat_pix_pad(r.is), npix = r.is.n * r.is.h * r.is.w;
  const uint64_t m_bytes = static_cast<uint64_t>(cout_pad * pix_pad) * 4;
  const Tensor& mt = workspace_->get(ctx_, 1, m_bytes);
  const BufferRange mr = mt.range(0, m_bytes);
  const std::string& name = r.info.name;
  const std::string suffix = t.emulated ? "_emulated" : "";
  const Groups gemm_groups{u32(pix_pad / (kWarps * kWarpPixels)), u32(cout_pad / (t.fm * t.m)), 1};
  auto spec = [&](bool accum) {
    return std::vector<uint32_t>{t.m, t.n, t.k, t.fm, t.fn, kWarps, kWarp, accum ? 1u : 0u, kWarps * kWarp,
                                 static_cast<uint32_t>(params_.kernel)};
  };
  if (implicit) {  // implicit GEMM: the input is gathered into shared memory, no scratch
    struct GemmPush {
      uint32_t in_off, in_bs, cin, h, w, npix, kpad, pix_pad;
    } gp{r.in.offset, r.in.batch_stride, u32(cin_), u32(r.is.h), u32(r.is.w), u32(npix), u32(kpad), u32(pix_pad)};
    cs.dispatch(kernel_pipeline(ctx_, "conv_kxk_coopmat" + suffix, spec(false), sizeof gp),
                {r.in.arg, {weight_coopmat_.range(), Access::read}, {mr, Access::write}}, gp, gemm_groups,
                {name + "_coopmat", r.info.flop, 2.0 * static_cast<double>(r.is.count() + cout_pad * kpad) +
                                                     4.0 * static_cast<double>(cout_pad * pix_pad)});
  }
  const int64_t chunk = implicit ? 0 : coopmat_chunk(r.is);
  const Tensor* vt = implicit ? nullptr : &workspace_->get(ctx_, 0, static_cast<uint64_t>(chunk * pix_pad) * 2);
  for (int64_t c0 = 0; !implicit && c0 < cin_; c0 += chunk) {
    const int64_t cn = std::min(chunk, cin_ - c0), cn_pad = round_up(cn, kPad);
    const double v_bytes = 2.0 * static_cast<double>(cn_pad * pix_pad);
    const BufferRange vr = vt->range(0, static_cast<size_t>(cn_pad * pix_pad) * 2);
    record_1x1_pack(cs, r, vr, c0, cn, cn_pad, pix_pad, "_coopmat");
    struct GemmPush {
      uint32_t chunk_pad, c_begin, cin_pad, pix_pad;
    } gp{u32(cn_pad), u32(c0), u32(kpad), u32(pix_pad)};
    cs.dispatch(kernel_pipeline(ctx_, "conv1x1_coopmat" + suffix, spec(c0 > 0), sizeof gp),
                {{vr, Access::read}, {weight_coopmat_.range(), Access::read},
                 {mr, c0 > 0 ? Access::read_write : Access::write}},
                gp, gemm_groups,
                {name + "_coopmat", r.info.flop * static_cast<double>(cn) / static_cast<double>(cin_),
                 v_bytes + 4.0 * static_cast<double>(cout_pad * (c0 > 0 ? 2 : 1) * pix_pad)});
  }
  record_1x1_output(cs, r, mr, pix_pad, "_coopmat");
}

}  // namespace vkunroll
