#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv2d.hpp"

#include <algorithm>
#include <cmath>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

// conv2d: the reference, construction, algorithm choice and the naive and blocked paths; the direct
// path is in conv2d_direct.cpp, Winograd and the 1x1 GEMM in conv2d_winograd.cpp.
namespace vkunroll {

namespace {
constexpr int64_t kDirectWideMinCin = 128;  // 1x1 convs from here use the wide direct blocks

// Buffer bytes [begin, end) from a slice's first element to its last (the batch items between included).
std::pair<uint64_t, uint64_t> element_span(const Slice& s) {
  const Shape& f = s.t->shape();
  const uint64_t e = dtype_size(s.t->dtype()), plane = static_cast<uint64_t>(f.h * f.w);
  const uint64_t first = static_cast<uint64_t>(s.n0 * f.c + s.c0) * plane;
  const uint64_t last = static_cast<uint64_t>((s.n0 + s.batch() - 1) * f.c + s.c0 + s.channels()) * plane;
  const uint64_t base = s.t->range().offset;
  return {base + first * e, base + last * e};
}

std::string conv_label(const std::string& name, const Conv2dParams& p) {
  // Appends (not operator+ chains): GCC 12 reports a false -Wrestrict on those at -O3.
  std::string label = name;
  label.append("_").append(std::to_string(p.kernel)).append("x").append(std::to_string(p.kernel));
  if (p.stride != 1) label.append("s").append(std::to_string(p.stride));
  return label;
}
}  // namespace

const char* conv_algo_name(ConvAlgo a) {
  switch (a) {
    case ConvAlgo::automatic: return "automatic";
    case ConvAlgo::naive: return "naive";
    case ConvAlgo::blocked: return "blocked";
    case ConvAlgo::winograd: return "winograd";
    case ConvAlgo::gemm: return "gemm";
    case ConvAlgo::direct: return "direct";
    case ConvAlgo::coopmat: return "coopmat";
    case ConvAlgo::pointwise: return "pointwise";
    case ConvAlgo::igemm_l: return "igemm_l";
    case ConvAlgo::igemm_m: return "igemm_m";
    case ConvAlgo::igemm_s: return "igemm_s";
    case ConvAlgo::igemm_n: return "igemm_n";
  }
  return "unknown";
}

bool is_igemm(ConvAlgo a) {
  return a == ConvAlgo::igemm_l || a == ConvAlgo::igemm_m || a == ConvAlgo::igemm_s || a == ConvAlgo::igemm_n;
}

int64_t conv_output_size(int64_t in, int kernel, int stride, int pad) {
  const int64_t span = in + 2 * pad - kernel;
  if (span < 0) return 0;
  return span / stride + 1;
}

void conv2d_ref(HostSlice in, HostSliceOut out, const HostTensor& weight, const HostTensor& bias,
                const Conv2dParams& p, std::optional<HostSlice> residual) {
  check_slice(in, "conv2d_ref", "input");
  check_slice(HostSlice(out), "conv2d_ref", "output");
  const int64_t cin = in.channels(), cout = out.channels(), k = p.kernel;
  if (weight.shape != Shape{cout, cin, k, k})
    throw Error("conv2d_ref: weight " + weight.shape.str() + ", expected " + Shape{cout, cin, k, k}.str());
  const int64_t oh = conv_output_size(in.height(), p.kernel, p.stride, p.pad);
  const int64_t ow = conv_output_size(in.width(), p.kernel, p.stride, p.pad);
  if (out.height() != oh || out.width() != ow || out.batch() != in.batch())
    throw Error("conv2d_ref: output " + out.shape().str() + ", expected " + Shape{in.batch(), cout, oh, ow}.str());
  if (residual) {
    check_slice(*residual, "conv2d_ref", "residual");
    if (residual->shape() != out.shape())
      throw Error("conv2d_ref: residual " + residual->shape().str() + ", expected " + out.shape().str());
  }
  for (int64_t n = 0; n < in.batch(); ++n)
    for (int64_t co = 0; co < cout; ++co)
      for (int64_t oy = 0; oy < oh; ++oy)
        for (int64_t ox = 0; ox < ow; ++ox) {
          double acc = bias.data.empty() ? 0.0 : bias.data[static_cast<size_t>(co)];
          for (int64_t ci = 0; ci < cin; ++ci)
            for (int64_t ky = 0; ky < k; ++ky) {
              const int64_t iy = oy * p.stride - p.pad + ky;
              if (iy < 0 || iy >= in.height()) continue;
              for (int64_t kx = 0; kx < k; ++kx) {
                const int64_t ix = ox * p.stride - p.pad + kx;
                if (ix < 0 || ix >= in.width()) continue;
                acc += static_cast<double>(in.at(n, ci, iy, ix)) * weight.at(co, ci, ky, kx);
              }
            }
          float v = apply_act(p.act, static_cast<float>(acc));
          if (residual) v += residual->at(n, co, oy, ox);
          out.at(n, co, oy, ox) = v;
        }
}

const Tensor& ConvWorkspace::get(Context& ctx, int slot, uint64_t bytes) {
  if (slot < 0) throw Error("ConvWorkspace: negative slot");
  if (slots_.size() <= static_cast<size_t>(slot)) slots_.resize(static_cast<size_t>(slot) + 1);
  auto& ptr = slots_[static_cast<size_t>(slot)];
  if (!ptr) ptr = std::make_unique<Tensor>();
  Tensor& t = *ptr;
  const int64_t floats = static_cast<int64_t>((bytes + 3) / 4);
  if (t.empty() || t.shape().count() < floats) {
    if (!t.empty()) retired_.push_back(std::move(t));
    t = Tensor(ctx, Shape{1, 1, 1, std::max<int64_t>(floats, 1)});
  }
  return t;
}

Conv2d::Conv2d(Context& ctx, const HostTensor& weight, const HostTensor& bias, const Conv2dParams& params,
               std::string name, std::shared_ptr<ConvWorkspace> workspace, const ConvOptions& options)
    : ctx_(ctx), name_(std::move(name)), params_(params), precision_(options.precision), workspace_(std::move(workspace)) {
  options.validate(name_);
  if (precision_ == Precision::fp16) require_fp16(ctx, name_);
  const int k = params.kernel;
  if (k < 1 || params.stride < 1 || params.pad < 0)
    throw Error(name_ + ": invalid kernel " + std::to_string(k) + " stride " + std::to_string(params.stride) +
                " pad " + std::to_string(params.pad));
  if (weight.shape.h != k || weight.shape.w != k || static_cast<int64_t>(weight.data.size()) != weight.shape.count())
    throw Error(name_ + ": weight " + weight.shape.str() + " is not [cout, cin, " + std::to_string(k) + ", " +
                std::to_string(k) + "]");
  cout_ = weight.shape.n;
  cin_ = weight.shape.c;
  if (!bias.data.empty() && static_cast<int64_t>(bias.data.size()) != cout_)
    throw Error(name_ + ": bias has " + std::to_string(bias.data.size()) + " values, " + std::to_string(cout_) +
                " output channels expected");
  // Only the packing `automatic` uses is uploaded now; the others (naive, blocked as the fallback,
  // direct) on first use, from this host copy.
  weight_host_ = weight;
  bias_host_ = bias.data.empty() ? std::vector<float>(static_cast<size_t>(cout_), 0.f) : bias.data;
  bias_ = to_device(ctx, HostTensor(Shape{1, 1, 1, cout_}, bias_host_));
  choose_blocking(options);
  gpu_family_ = options.gpu_family;
  const bool wino_s2 = k == 3 && params.stride == 2 && params.pad == 1;
  if ((k == 3 && params.stride == 1 && params.pad == 1) || (k == 5 && params.stride == 1 && params.pad == 2) || wino_s2)
    pack_winograd();
  if (k == 1 && params.stride == 1 && params.pad == 0) pack_gemm();
  if (weight_winograd_.empty() && weight_gemm_.empty()) pack_blocked();
}

void Conv2d::choose_blocking(const ConvOptions& options) {
  const int k = params_.kernel;
  // 16 channels per invocation halve the input loads per FMA where cout allows it without waste.
  blocked_cob_ = options.blocked_cob ? options.blocked_cob : (cout_ % 16 == 0 ? 16 : 8);
  blocked_px_ = static_cast<uint32_t>(options.blocked_px ? options.blocked_px : 8);
  direct_cob_ = cout_ <= 4 ? 4 : (cout_ <= 8 ? 8 : 16);
  // Wide 1x1 convs: more output channels per invocation, so each loaded input value feeds more
  // FMAs; 4 pixels x 48 or 8 x 32 measured best there (bench_kernels on lavapipe).
  if (k == 1 && cin_ >= kDirectWideMinCin && cout_ % 48 == 0) {
    direct_cob_ = 48;
    direct_px_ = 4;
  } else if (k == 1 && cin_ >= kDirectWideMinCin && cout_ % 32 == 0) {
    direct_cob_ = 32;
  } else if (k == 1 && params_.stride == 1 && direct_cob_ == 16) {
    direct_px_ = 12;  // narrower 1x1 convs (32->32, 64->64): 12 px x 16 channels, 1.1-1.2x over 8 px
  }
  if (options.direct_cob) direct_cob_ = options.direct_cob;
  // Heads (1-4 output channels): 8 rows per invocation, 1.1-1.5x over 4 (lavapipe, pred convs).
  direct_py_ = (cout_ <= 4 && k > 1) ? 8 : 1;
  if (options.direct_px) direct_px_ = static_cast<uint32_t>(options.direct_px);
  if (options.direct_py) direct_py_ = static_cast<uint32_t>(options.direct_py);
  gemm_cob_ = options.gemm_cob ? options.gemm_cob : (cout_ % 16 == 0 ? 16 : 8);
  gemm_tv_ = static_cast<uint32_t>(options.gemm_tv ? options.gemm_tv : 4);
  if (k == 5 && params_.stride == 1 && options.winograd_tile != 6) winograd_form_ = WinogradForm::f4x4_5x5;
  if (k == 3 && params_.stride == 1 && options.winograd_tile == 8) winograd_form_ = WinogradForm::f6x6_3x3;
  gemm_cout_pad_ = (cout_ + gemm_cob_ - 1) / gemm_cob_ * gemm_cob_;
  // pointwise: 2 units (pixel pairs) x 12 channels, among the fastest of 1-4 units x 4-32 channels
  // on the LFF conv (bench_kernels on lavapipe; 2 x 6 and 2 x 8 within the noise).
  pointwise_cob_ = options.pointwise_cob ? options.pointwise_cob : std::min<int64_t>(cout_, 12);
  pointwise_px_ = static_cast<uint32_t>(options.pointwise_px ? options.pointwise_px : 2);
}

Tensor Conv2d::upload_weights(const std::vector<float>& w) const {
  return vkunroll::upload_weights(ctx_, w, precision_, name_);
}

void Conv2d::pack_naive() const {
  if (!weight_.empty()) return;
  weight_ = upload_weights(weight_host_.data);
}

void Conv2d::pack_blocked() const {
  if (!weight_blocked_.empty()) return;
  // Blocked layout: [cout/COB][cin][k][k][COB], output channels zero-padded to a multiple of COB.
  const HostTensor& weight = weight_host_;
  const std::vector<float>& b = bias_host_;
  const int64_t BC = blocked_cob_, kk = static_cast<int64_t>(params_.kernel) * params_.kernel;
  const int64_t cob = (cout_ + BC - 1) / BC;
  std::vector<float> wb(static_cast<size_t>(cob * cin_ * kk * BC), 0.f), bb(static_cast<size_t>(cob * BC), 0.f);
  for (int64_t co = 0; co < cout_; ++co) {
    bb[static_cast<size_t>(co)] = b[static_cast<size_t>(co)];
    for (int64_t ci = 0; ci < cin_; ++ci)
      for (int64_t t = 0; t < kk; ++t)
        wb[static_cast<size_t>((((co / BC) * cin_ + ci) * kk + t) * BC + co % BC)] =
            weight.data[static_cast<size_t>((co * cin_ + ci) * kk + t)];
  }
  weight_blocked_ = upload_weights(wb);
  bias_blocked_ = to_device(ctx_, HostTensor(Shape{1, 1, 1, static_cast<int64_t>(bb.size())}, bb));
}

void Conv2d::set_winograd_scratch_limit(uint64_t bytes) { winograd_scratch_limit_ = bytes; }

bool Conv2d::supports(ConvAlgo algo) const {
  switch (algo) {
    case ConvAlgo::winograd: return !weight_winograd_.empty();
    case ConvAlgo::gemm: return !weight_gemm_.empty();
    case ConvAlgo::automatic:
    case ConvAlgo::naive:
    case ConvAlgo::blocked: return true;
    case ConvAlgo::direct: return direct_cob_ % 4 == 0 && direct_chunks().chunk >= 1;
    case ConvAlgo::coopmat: return coopmat_applies();
    case ConvAlgo::pointwise: return pointwise_applies();
    case ConvAlgo::igemm_l:
    case ConvAlgo::igemm_m:
    case ConvAlgo::igemm_s:
    case ConvAlgo::igemm_n: return true;
    default: return false;
  }
}

ConvAlgo gpu_conv_heuristic(const GpuConvFacts& f) {
  // The GPU family, one dispatch per conv. The H100 and H200 runs (docs/gpu_nvidia.md) measured the
  // CPU-shaped algorithms at 2-57x cuDNN: Winograd's 256-accumulator GEMM spills, `direct` reads
  // weights through uniform buffers, and both run 3 dispatches or more per conv. In fp16 the tensor
  // cores (coopmat) where the device has them; otherwise the tile whose channel side fits cout, the
  // 128 x 128 tile where it still gives about two workgroups per shader core (split-K covers the rest).
  if (f.coopmat) return ConvAlgo::coopmat;
  if (f.cout <= 16) return ConvAlgo::igemm_n;
  if (f.cout <= 32) return ConvAlgo::igemm_s;
  const int64_t cores = f.cores > 0 ? f.cores : 128;
  const int64_t large_groups = ((f.pixels + 127) / 128) * ((f.cout + 127) / 128);
  if (f.cout >= 128 && large_groups >= 2 * cores) return ConvAlgo::igemm_l;
  return ConvAlgo::igemm_m;
}

ConvAlgo Conv2d::choose_algorithm(int64_t h, int64_t w) const {
  // Measured on lavapipe (bench_kernels): Winograd F(4,3) wins for every 3x3 stride-1 shape of the
  // model; tiny images (one tile row or column) gain nothing from it.
  // The direct path (weights from a uniform buffer, input through a texel buffer) beats Winograd for
  // 1-4 output channels (Winograd pads them to 8; there only where one dispatch per channel block
  // holds all input channels) and the GEMM for 1x1 convs with <= 64 input channels (no pack and
  // epilogue passes) or with the wide blocks (32 or 48 output channels per invocation).
  if (ctx_.info().type != VK_PHYSICAL_DEVICE_TYPE_CPU || gpu_family_) return gpu_choice(Shape{1, cin_, h, w});
  const bool direct_whole = supports(ConvAlgo::direct) && direct_chunks().chunk >= cin_;
  if (direct_whole && cout_ <= 4 && params_.kernel > 1) return ConvAlgo::direct;
  // 3x3 stride 2: direct (input through a texel buffer) runs 1.6-2x the speed of Winograd on the
  // phase images, in input-channel chunks too.
  if (supports(ConvAlgo::direct) && params_.kernel == 3 && params_.stride == 2) return ConvAlgo::direct;
  // Few channels (the small UNets' 8-channel levels): Winograd pads cout to 8 and runs 3 dispatches;
  // direct 1.1-2.7x faster there (8->8 @288x352 3.8 against 10.4 ms, 16->8 6.2 / 8.1, 43->8 15.7 /
  // 17.9, 8->16 7.4 / 8.4; 67->8 and 16->16 level).
  if (direct_whole && params_.kernel == 3 && params_.stride == 1 && ((cout_ <= 8 && cin_ <= 48) || cin_ * cout_ <= 128))
    return ConvAlgo::direct;
  if (supports(ConvAlgo::winograd) && h >= 4 * params_.stride && w >= 4 * params_.stride) return ConvAlgo::winograd;
  if (direct_whole && supports(ConvAlgo::gemm) && cin_ <= 64) return ConvAlgo::direct;
  // From 256 input channels the texel GEMM (V in its own order) beats the wide direct blocks: LFF
  // 336->96 50 against 70 ms, GFF.0 960->96 151 against 219, 256->256 7.3 against 8.6 (128->128 level).
  if (texel_fetch_ && supports(ConvAlgo::gemm) && cin_ >= 256 && h * w >= 64) return ConvAlgo::gemm;
  // Below that the wide blocks beat the GEMM.
  if (supports(ConvAlgo::direct) && supports(ConvAlgo::gemm) && direct_cob_ >= 32) return ConvAlgo::direct;
  if (supports(ConvAlgo::gemm) && h * w >= 64) return ConvAlgo::gemm;
  return ConvAlgo::blocked;
}

std::vector<ConvAlgo> Conv2d::candidates(const Shape& in, bool residual_in_output) const {
  std::vector<ConvAlgo> out;
  // Every named algorithm after naive, so that one added to the enum is timed where supports() allows it.
  for (uint32_t v = static_cast<uint32_t>(ConvAlgo::naive) + 1; v < 32; ++v) {
    const ConvAlgo a = static_cast<ConvAlgo>(v);
    if (std::string(conv_algo_name(a)) == "unknown" || !supports(a) || !supports(a, in)) continue;
    if (residual_in_output && accumulates_in_output(a)) continue;
    out.push_back(a);
  }
  return out;
}

Shape Conv2d::output_shape(const Shape& in) const {
  return {in.n, cout_, conv_output_size(in.h, params_.kernel, params_.stride, params_.pad),
          conv_output_size(in.w, params_.kernel, params_.stride, params_.pad)};
}

double Conv2d::flop(const Shape& in) const {
  const Shape o = output_shape(in);
  return 2.0 * static_cast<double>(o.count()) * static_cast<double>(cin_) * params_.kernel * params_.kernel;
}

ConvAlgo Conv2d::record(CommandStream& cs, Slice in, Slice out, std::optional<Slice> residual) const {
  return record(cs, in, out, residual, ConvAlgo::automatic);
}

ConvAlgo Conv2d::resolve_algorithm(const Shape& in, ConvAlgo algo, bool residual_in_output) const {
  if (algo != ConvAlgo::automatic) return algo;
  const bool gpu = ctx_.info().type != VK_PHYSICAL_DEVICE_TYPE_CPU || gpu_family_;
  algo = gpu ? gpu_choice(in) : choose_algorithm(in.h, in.w);
  // direct or pointwise in several chunks accumulates in the output, so it cannot add a residual
  // that overlaps it.
  if (accumulates_in_output(algo) && residual_in_output) algo = supports(ConvAlgo::gemm) ? ConvAlgo::gemm : ConvAlgo::winograd;
  if (!supports(algo, in)) algo = ConvAlgo::blocked;
  return algo;
}

bool Conv2d::texel_fits(uint64_t bytes, uint64_t texel_bytes) const {
  return texel_fetch_ && texel_view_fits(ctx_.info(), bytes, texel_bytes);
}

Arg Conv2d::input_texel_arg(const Recording& r) const {
  Arg a = r.in.arg;
  if (precision_ == Precision::fp16) a.texel_format = VK_FORMAT_R16_SFLOAT;
  return a;
}

bool Conv2d::accumulates_in_output(ConvAlgo a) const {
  if (a == ConvAlgo::direct) return direct_chunks().chunk < cin_;
  if (a == ConvAlgo::pointwise) return pointwise_chunks().chunk < cin_;
  return false;
}

bool Conv2d::residual_overlaps_output(const Slice& out, const std::optional<Slice>& residual) const {
  if (!residual || residual->t->range().buffer != out.t->range().buffer) return false;
  const auto [rb, re] = element_span(*residual);
  const auto [ob, oe] = element_span(out);
  return ob < re && rb < oe;
}

ConvAlgo Conv2d::record(CommandStream& cs, Slice in, Slice out, std::optional<Slice> residual, ConvAlgo algo,
                        WinogradInputCache* shared_v) const {
  check_slice(in, name_, "input");
  check_slice(out, name_, "output");
  check_precision(in, precision_, name_, "input");
  check_precision(out, precision_, name_, "output");
  const Shape is = in.shape(), os = out.shape(), expect = output_shape(is);
  if (is.c != cin_)
    throw Error(name_ + ": input has " + std::to_string(is.c) + " channels, the weights expect " + std::to_string(cin_));
  if (expect.h <= 0 || expect.w <= 0)
    throw Error(name_ + ": input " + is.str() + " is smaller than the kernel " + std::to_string(params_.kernel));
  if (os != expect) throw Error(name_ + ": output slice " + os.str() + ", expected " + expect.str());
  if (residual) {
    check_slice(*residual, name_, "residual");
    check_precision(*residual, precision_, name_, "residual");
    if (residual->shape() != expect)
      throw Error(name_ + ": residual slice " + residual->shape().str() + ", expected " + expect.str());
  }
  algo = resolve_algorithm(is, algo, algo == ConvAlgo::automatic && residual_overlaps_output(out, residual));
  if (!supports(algo, is))
    throw Error(name_ + ": algorithm " + std::string(conv_algo_name(algo)) + " does not apply to kernel " +
                std::to_string(params_.kernel) + " stride " + std::to_string(params_.stride));
  if (accumulates_in_output(algo) && residual_overlaps_output(out, residual))
    throw Error(name_ + ": the " + std::string(conv_algo_name(algo)) +
                " algorithm accumulates in the output, which overlaps the residual");

  Recording r;
  r.is = is;
  r.os = os;
  r.in = bind_slice(in, Access::read);
  r.out = bind_slice(out, Access::write);
  r.has_res = residual.has_value();
  r.res = residual ? bind_slice(*residual, Access::read) : BoundSlice{{bias_.range(), Access::read}, 0, 0};
  r.push = {r.in.offset, r.in.batch_stride, r.res.offset, r.res.batch_stride, r.out.offset, r.out.batch_stride,
            static_cast<uint32_t>(cin_), static_cast<uint32_t>(is.h), static_cast<uint32_t>(is.w),
            static_cast<uint32_t>(cout_), static_cast<uint32_t>(os.h), static_cast<uint32_t>(os.w),
            static_cast<uint32_t>(params_.pad)};
  r.spec = {static_cast<uint32_t>(params_.kernel), static_cast<uint32_t>(params_.stride),
            static_cast<uint32_t>(params_.act.kind), spec_float(params_.act.slope), residual ? 1u : 0u};
  const double e = static_cast<double>(elem_bytes());
  const double bytes = e * (static_cast<double>(is.count()) + static_cast<double>(os.count()) * (residual ? 2 : 1) +
                            static_cast<double>(cin_ * cout_ * params_.kernel * params_.kernel));
  r.info = {conv_label(name_, params_), flop(is), bytes};
  r.shared_v = shared_v && shared_v->active() ? shared_v : nullptr;
  switch (algo) {
    case ConvAlgo::naive: record_naive(cs, r); break;
    case ConvAlgo::blocked: record_blocked(cs, r); break;
    case ConvAlgo::direct: record_direct(cs, r); break;
    case ConvAlgo::winograd: record_winograd(cs, r); break;
    case ConvAlgo::gemm: record_gemm(cs, r); break;
    case ConvAlgo::coopmat: record_coopmat(cs, r); break;
    case ConvAlgo::pointwise: record_pointwise(cs, r); break;
    case ConvAlgo::igemm_l:
    case ConvAlgo::igemm_m:
    case ConvAlgo::igemm_s:
    case ConvAlgo::igemm_n: record_igemm(cs, r, algo); break;
    default: throw Error(name_ + ": algorithm " + std::string(conv_algo_name(algo)) + " is not implemented");
  }
  return algo;
}

void Conv2d::record_naive(CommandStream& cs, const Recording& r) const {
  pack_naive();
  const Pipeline& pl = kernel_pipeline(ctx_, shader("conv2d_naive"), r.spec, sizeof(Push));
  cs.dispatch(pl, {r.in.arg, {weight_.range(), Access::read}, {bias_.range(), Access::read}, r.res.arg, r.out.arg},
              r.push,
              Groups{static_cast<uint32_t>((r.os.w + 7) / 8), static_cast<uint32_t>((r.os.h + 7) / 8),
                     static_cast<uint32_t>(r.os.n * cout_)},
              r.info);
}

void Conv2d::record_blocked(CommandStream& cs, const Recording& r) const {
  const uint32_t px = blocked_px_;
  pack_blocked();
  std::vector<uint32_t> bspec = r.spec;
  bspec.push_back(px);
  bspec.push_back(static_cast<uint32_t>(blocked_cob_ / 4));
  const Pipeline& pl = kernel_pipeline(ctx_, shader("conv2d_blocked"), bspec, sizeof(Push));
  // One workgroup layer per batch item and block of blocked_cob_ channels: the shader's COB.
  const auto cob = static_cast<uint32_t>((cout_ + blocked_cob_ - 1) / blocked_cob_);
  cs.dispatch(pl,
              {r.in.arg, {weight_blocked_.range(), Access::read}, {bias_blocked_.range(), Access::read}, r.res.arg,
               r.out.arg},
              r.push, flat_groups(r.os.h * ((r.os.w + px - 1) / px), static_cast<uint32_t>(r.os.n) * cob), r.info);
}

}  // namespace vkunroll
