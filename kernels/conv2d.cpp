#include "kernels/conv2d.hpp"

#include <algorithm>

#include "runtime/context.hpp"
#include "runtime/pipeline.hpp"

namespace vkunroll {

namespace {
constexpr int64_t kDirectWideMinCin = 128;  // 1x1 convs from here use the wide direct blocks

// Groups of 64 for `n` invocations numbered x + y * (64 gx) in the shader (y only past the limit).
Groups flat_groups(int64_t n, uint32_t z) {
  const int64_t g = (n + 63) / 64;
  const int64_t gx = std::min<int64_t>(g, 65535);
  return {static_cast<uint32_t>(gx), static_cast<uint32_t>((g + gx - 1) / gx), z};
}

struct ConvPush {
  uint32_t in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint32_t cin, h, w, cout, oh, ow, pad;
  uint32_t co0 = 0;  // direct: first output channel of the dispatch (the other shaders ignore it)
};

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
  }
  return "unknown";
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

const Tensor& ConvWorkspace::get(Context& ctx, int slot, int64_t floats) {
  if (slot < 0) throw Error("ConvWorkspace: negative slot");
  if (slots_.size() <= static_cast<size_t>(slot)) slots_.resize(static_cast<size_t>(slot) + 1);
  auto& ptr = slots_[static_cast<size_t>(slot)];
  if (!ptr) ptr = std::make_unique<Tensor>();
  Tensor& t = *ptr;
  if (t.empty() || t.shape().count() < floats) {
    if (!t.empty()) retired_.push_back(std::move(t));
    t = Tensor(ctx, Shape{1, 1, 1, std::max<int64_t>(floats, 1)});
  }
  return t;
}

Conv2d::Conv2d(Context& ctx, const HostTensor& weight, const HostTensor& bias, const Conv2dParams& params,
               std::string name, std::shared_ptr<ConvWorkspace> workspace, const ConvOptions& options)
    : ctx_(ctx), name_(std::move(name)), params_(params), workspace_(std::move(workspace)) {
  options.validate(name_);
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
  std::vector<float> b = bias.data.empty() ? std::vector<float>(static_cast<size_t>(cout_), 0.f) : bias.data;

  // Only the packing `automatic` uses is uploaded now; the others (naive, blocked as the fallback,
  // direct) on first use, from this host copy.
  weight_host_ = weight;
  bias_host_ = b;
  bias_ = HostTensor(Shape{1, 1, 1, cout_}, b).to_device(ctx);
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
  } else if (k == 1 && params.stride == 1 && direct_cob_ == 16) {
    direct_px_ = 12;  // narrower 1x1 convs (32->32, 64->64): 12 px x 16 channels, 1.1-1.2x over 8 px
  }
  if (options.direct_cob) direct_cob_ = options.direct_cob;
  // Heads (1-4 output channels): 8 rows per invocation, 1.1-1.5x over 4 (lavapipe, pred convs).
  direct_py_ = (cout_ <= 4 && k > 1) ? 8 : 1;
  if (options.direct_px) direct_px_ = static_cast<uint32_t>(options.direct_px);
  if (options.direct_py) direct_py_ = static_cast<uint32_t>(options.direct_py);
  gemm_cob_ = options.gemm_cob ? options.gemm_cob : (cout_ % 16 == 0 ? 16 : 8);
  gemm_tv_ = static_cast<uint32_t>(options.gemm_tv ? options.gemm_tv : 4);
  gemm_cout_pad_ = (cout_ + gemm_cob_ - 1) / gemm_cob_ * gemm_cob_;

  const bool wino_s2 = k == 3 && params.stride == 2 && params.pad == 1;
  if ((k == 3 && params.stride == 1 && params.pad == 1) || (k == 5 && params.stride == 1 && params.pad == 2) || wino_s2) {
    // Winograd F(4x4, 3x3): U = G g G^T in double, [36][KS*KS*cin][cout_pad]. A 5x5 kernel is split
    // into four 3x3 blocks at offsets (0|3, 0|3) (zero beyond 5): four 3x3 convs on shifted inputs,
    // summed by the GEMM as KS*KS*cin virtual input channels.
    // Stride 2: four phase images (a, b); tap (i', j') of the 3x3 kernel on phase a reads kernel row
    // 1 (a = 0, i' = 1) or rows 0 and 2 (a = 1, i' = 0 and 1); every other tap is zero.
    winograd_ks_ = (k == 5 || wino_s2) ? 2 : 1;
    const int64_t cv = winograd_ks_ * winograd_ks_ * cin_;
    static const double Gm[6][3] = {{1.0 / 4, 0, 0},           {-1.0 / 6, -1.0 / 6, -1.0 / 6}, {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                    {1.0 / 24, 1.0 / 12, 1.0 / 6}, {1.0 / 24, -1.0 / 12, 1.0 / 6}, {0, 0, 1}};
    std::vector<float> u(static_cast<size_t>(36 * cv * gemm_cout_pad_), 0.f);
    for (int64_t sblk = 0; sblk < winograd_ks_ * winograd_ks_; ++sblk) {
      const int64_t oy = 3 * (sblk / winograd_ks_), ox = 3 * (sblk % winograd_ks_);
      const int64_t pa = sblk / 2, pb = sblk % 2;
      auto phase_tap = [](int64_t phase, int64_t t) -> int64_t {
        if (phase == 0) return t == 1 ? 1 : -1;  // row 2u: kernel row 1 at u = oy
        return t == 0 ? 0 : (t == 1 ? 2 : -1);   // row 2u+1: kernel row 0 at u = oy-1, row 2 at u = oy
      };
      for (int64_t co = 0; co < cout_; ++co)
        for (int64_t ci = 0; ci < cin_; ++ci) {
          auto g = [&](int64_t y, int64_t x) -> double {
            if (wino_s2) {
              const int64_t ky = phase_tap(pa, y), kx = phase_tap(pb, x);
              return (ky >= 0 && kx >= 0) ? weight.at(co, ci, ky, kx) : 0.0;
            }
            return (oy + y < k && ox + x < k) ? weight.at(co, ci, oy + y, ox + x) : 0.0;
          };
          double gg[6][3];
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 3; ++j) {
              double acc = 0;
              for (int t = 0; t < 3; ++t) acc += Gm[i][t] * g(t, j);
              gg[i][j] = acc;
            }
          const int64_t vc = sblk * cin_ + ci;
          for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) {
              double acc = 0;
              for (int t = 0; t < 3; ++t) acc += gg[i][t] * Gm[j][t];
              u[static_cast<size_t>(((i * 6 + j) * cv + vc) * gemm_cout_pad_ + co)] = static_cast<float>(acc);
            }
        }
    }
    weight_winograd_ = HostTensor(Shape{1, 1, 1, static_cast<int64_t>(u.size())}, u).to_device(ctx);
  }
  if (k == 1 && params.stride == 1 && params.pad == 0) {
    std::vector<float> u(static_cast<size_t>(cin_ * gemm_cout_pad_), 0.f);
    for (int64_t co = 0; co < cout_; ++co)
      for (int64_t ci = 0; ci < cin_; ++ci)
        u[static_cast<size_t>(ci * gemm_cout_pad_ + co)] = weight.data[static_cast<size_t>(co * cin_ + ci)];
    weight_gemm_ = HostTensor(Shape{1, 1, 1, static_cast<int64_t>(u.size())}, u).to_device(ctx);
  }
  if (weight_winograd_.empty() && weight_gemm_.empty()) pack_blocked();
}

void Conv2d::pack_naive() const {
  if (!weight_.empty()) return;
  weight_ = HostTensor(Shape{1, 1, 1, weight_host_.shape.count()}, weight_host_.data).to_device(ctx_);
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
  weight_blocked_ = HostTensor(Shape{1, 1, 1, static_cast<int64_t>(wb.size())}, wb).to_device(ctx_);
  bias_blocked_ = HostTensor(Shape{1, 1, 1, static_cast<int64_t>(bb.size())}, bb).to_device(ctx_);
}

UniformSlabChunks Conv2d::direct_chunks() const {
  return uniform_slab_chunks(ctx_.info(), cin_, static_cast<int64_t>(params_.kernel) * params_.kernel * direct_cob_ * 4,
                             direct_chunk_limit_);
}

void Conv2d::pack_direct() const {
  if (!weight_direct_.empty()) return;
  // [cout/COB][cin][k*k][COB], zero-padded channels, plus one chunk of zeros at the end so that
  // every dispatch can bind a whole slab (the uniform block has a fixed size).
  const int64_t kk = static_cast<int64_t>(params_.kernel) * params_.kernel, cob = direct_cob_;
  const int64_t blocks = (cout_ + cob - 1) / cob;
  // Each block's channels are padded to cin_pad so every chunk's slab starts aligned.
  const UniformSlabChunks ch = direct_chunks();
  const int64_t cin_pad = ch.cin_pad;
  std::vector<float> wd(static_cast<size_t>((blocks * cin_pad + ch.max) * kk * cob), 0.f);
  for (int64_t co = 0; co < cout_; ++co)
    for (int64_t ci = 0; ci < cin_; ++ci)
      for (int64_t t = 0; t < kk; ++t)
        wd[static_cast<size_t>((((co / cob) * cin_pad + ci) * kk + t) * cob + co % cob)] =
            weight_host_.data[static_cast<size_t>((co * cin_ + ci) * kk + t)];
  weight_direct_ = HostTensor(Shape{1, 1, 1, static_cast<int64_t>(wd.size())}, wd).to_device(ctx_);
}

namespace {
struct WinogradSizes {
  int64_t tiles_x_pad, tiles_y, ngroups, tiles_pad;  // groups of 4 horizontally adjacent tiles
};
WinogradSizes winograd_sizes(const Shape& in) {
  WinogradSizes s{};
  s.tiles_x_pad = ((in.w + 3) / 4 + 3) / 4 * 4;
  s.tiles_y = (in.h + 3) / 4;
  s.ngroups = in.n * s.tiles_y * s.tiles_x_pad / 4;
  s.tiles_pad = (s.ngroups * 4 + 15) / 16 * 16;  // whole GEMM blocks of up to 16 tiles
  return s;
}
}  // namespace

void Conv2d::set_winograd_scratch_limit(uint64_t bytes) { winograd_scratch_limit_ = bytes; }

static int64_t gemm_pix_pad(const Shape& in) { return (in.n * in.h * in.w + 15) / 16 * 16; }

int64_t Conv2d::winograd_chunk(const Shape& in) const {
  const uint64_t limit = std::min<uint64_t>(ctx_.info().max_storage_buffer_range, winograd_scratch_limit_);
  if (!weight_gemm_.empty()) {  // 1x1 gemm path: one position, pixels padded to 8
    const uint64_t per_channel = static_cast<uint64_t>(gemm_pix_pad(in)) * 4;
    return std::min<int64_t>(cin_, static_cast<int64_t>(limit / per_channel));
  }
  const WinogradSizes ws = winograd_sizes(output_shape(in));
  const uint64_t per_channel = 36ull * static_cast<uint64_t>(ws.tiles_pad) * 4;
  const int64_t cv = winograd_ks_ * winograd_ks_ * cin_;
  return std::min<int64_t>(cv, static_cast<int64_t>(limit / per_channel));
}

bool Conv2d::supports(ConvAlgo algo, const Shape& in) const {
  if (!supports(algo)) return false;
  if (algo == ConvAlgo::gemm)
    return static_cast<uint64_t>(gemm_cout_pad_ * gemm_pix_pad(in)) * 4 <= ctx_.info().max_storage_buffer_range &&
           winograd_chunk(in) >= 1;
  if (algo != ConvAlgo::winograd) return true;
  // V is transformed in chunks of input channels; M (all output channels) must fit one binding.
  const WinogradSizes ws = winograd_sizes(output_shape(in));
  const uint64_t m_bytes = 36ull * static_cast<uint64_t>(gemm_cout_pad_ * ws.tiles_pad) * 4;
  return m_bytes <= ctx_.info().max_storage_buffer_range && winograd_chunk(in) >= 1;
}

bool Conv2d::supports(ConvAlgo algo) const {
  switch (algo) {
    case ConvAlgo::winograd: return !weight_winograd_.empty();
    case ConvAlgo::gemm: return !weight_gemm_.empty();
    case ConvAlgo::automatic:
    case ConvAlgo::naive:
    case ConvAlgo::blocked: return true;
    case ConvAlgo::direct: return direct_cob_ % 4 == 0 && direct_chunks().chunk >= 1;
    default: return false;
  }
}

ConvAlgo Conv2d::choose_algorithm(int64_t h, int64_t w) const {
  // Measured on lavapipe (bench_kernels): Winograd F(4,3) wins for every 3x3 stride-1 shape of the
  // model; tiny images (one tile row or column) gain nothing from it.
  // The direct path (weights from a uniform buffer, input through a texel buffer) beats Winograd for
  // 1-4 output channels (Winograd pads them to 8; there only where one dispatch per channel block
  // holds all input channels) and the GEMM for 1x1 convs with <= 64 input channels (no pack and
  // epilogue passes) or with the wide blocks (32 or 48 output channels per invocation).
  // On a GPU (measured on an H100, docs/gpu_nvidia.md) the uniform-buffer `direct` path, built for
  // llvmpipe, is 3-10x slower than `blocked`. Winograd wins there as here, except for 1-4 output
  // channels; 1x1 convs take the GEMM (`blocked` led by 20% alone but was 10x slower in the model,
  // on batch-2 channel slices).
  if (ctx_.info().type != VK_PHYSICAL_DEVICE_TYPE_CPU) {
    if (cout_ > 4 && supports(ConvAlgo::winograd) && h >= 4 * params_.stride && w >= 4 * params_.stride)
      return ConvAlgo::winograd;
    if (supports(ConvAlgo::gemm) && h * w >= 64) return ConvAlgo::gemm;
    return ConvAlgo::blocked;
  }
  const bool direct_whole = supports(ConvAlgo::direct) && direct_chunks().chunk >= cin_;
  if (direct_whole && cout_ <= 4 && params_.kernel > 1) return ConvAlgo::direct;
  // 3x3 stride 2: direct (input through a texel buffer) runs 1.6-2x the speed of Winograd on the
  // phase images, in input-channel chunks too.
  if (supports(ConvAlgo::direct) && params_.kernel == 3 && params_.stride == 2) return ConvAlgo::direct;
  if (supports(ConvAlgo::winograd) && h >= 4 * params_.stride && w >= 4 * params_.stride) return ConvAlgo::winograd;
  if (direct_whole && supports(ConvAlgo::gemm) && cin_ <= 64) return ConvAlgo::direct;
  // The wide blocks beat the GEMM even in several input-channel chunks (GFF.0, 960 channels: 3).
  if (supports(ConvAlgo::direct) && supports(ConvAlgo::gemm) && direct_cob_ >= 32) return ConvAlgo::direct;
  if (supports(ConvAlgo::gemm) && h * w >= 64) return ConvAlgo::gemm;
  return ConvAlgo::blocked;
}

Shape Conv2d::output_shape(const Shape& in) const {
  return {in.n, cout_, conv_output_size(in.h, params_.kernel, params_.stride, params_.pad),
          conv_output_size(in.w, params_.kernel, params_.stride, params_.pad)};
}

double Conv2d::flop(const Shape& in) const {
  const Shape o = output_shape(in);
  return 2.0 * static_cast<double>(o.count()) * static_cast<double>(cin_) * params_.kernel * params_.kernel;
}

void Conv2d::record(CommandStream& cs, Slice in, Slice out, std::optional<Slice> residual) const {
  record(cs, in, out, residual, ConvAlgo::automatic);
}

void Conv2d::record(CommandStream& cs, Slice in, Slice out, std::optional<Slice> residual, ConvAlgo algo) const {
  check_slice(in, name_, "input");
  check_slice(out, name_, "output");
  const Shape is = in.shape(), os = out.shape(), expect = output_shape(is);
  if (is.c != cin_)
    throw Error(name_ + ": input has " + std::to_string(is.c) + " channels, the weights expect " + std::to_string(cin_));
  if (expect.h <= 0 || expect.w <= 0)
    throw Error(name_ + ": input " + is.str() + " is smaller than the kernel " + std::to_string(params_.kernel));
  if (os != expect) throw Error(name_ + ": output slice " + os.str() + ", expected " + expect.str());
  if (residual) {
    check_slice(*residual, name_, "residual");
    if (residual->shape() != expect)
      throw Error(name_ + ": residual slice " + residual->shape().str() + ", expected " + expect.str());
  }
  // direct in several chunks accumulates in the output, so it cannot add a residual that overlaps it.
  const auto residual_overlaps_output = [&] {
    if (!residual || residual->t->range().buffer != out.t->range().buffer) return false;
    const auto [rb, re] = element_span(*residual);
    const auto [ob, oe] = element_span(out);
    return ob < re && rb < oe;
  };
  if (algo == ConvAlgo::automatic) {
    algo = choose_algorithm(is.h, is.w);
    if (algo == ConvAlgo::direct && direct_chunks().chunk < cin_ && residual_overlaps_output())
      algo = supports(ConvAlgo::gemm) ? ConvAlgo::gemm : ConvAlgo::winograd;
    if (!supports(algo, is)) algo = ConvAlgo::blocked;
  }
  if (!supports(algo, is))
    throw Error(name_ + ": algorithm " + std::string(conv_algo_name(algo)) + " does not apply to kernel " +
                std::to_string(params_.kernel) + " stride " + std::to_string(params_.stride));

  const BoundSlice bi = bind_slice(in, Access::read), bo = bind_slice(out, Access::write);
  const BoundSlice br = residual ? bind_slice(*residual, Access::read) : BoundSlice{{bias_.range(), Access::read}, 0, 0};
  ConvPush p{bi.offset, bi.batch_stride, br.offset, br.batch_stride, bo.offset, bo.batch_stride,
             static_cast<uint32_t>(cin_), static_cast<uint32_t>(is.h), static_cast<uint32_t>(is.w),
             static_cast<uint32_t>(cout_), static_cast<uint32_t>(os.h), static_cast<uint32_t>(os.w),
             static_cast<uint32_t>(params_.pad)};
  const std::vector<uint32_t> spec{static_cast<uint32_t>(params_.kernel), static_cast<uint32_t>(params_.stride),
                                   static_cast<uint32_t>(params_.act.kind), spec_float(params_.act.slope),
                                   residual ? 1u : 0u};
  const double bytes = 4.0 * (static_cast<double>(is.count()) + static_cast<double>(os.count()) * (residual ? 2 : 1) +
                              static_cast<double>(cin_ * cout_ * params_.kernel * params_.kernel));
  const DispatchInfo info{conv_label(name_, params_), flop(is), bytes};
  switch (algo) {
    case ConvAlgo::naive: {
      pack_naive();
      const Pipeline& pl = ctx_.pipeline("conv2d_naive", spec, sizeof(ConvPush));
      cs.dispatch(pl, {bi.arg, {weight_.range(), Access::read}, {bias_.range(), Access::read}, br.arg, bo.arg}, p,
                  Groups{static_cast<uint32_t>((os.w + 7) / 8), static_cast<uint32_t>((os.h + 7) / 8),
                         static_cast<uint32_t>(os.n * cout_)},
                  info);
      return;
    }
    case ConvAlgo::blocked: {
      const uint32_t px = blocked_px_;
      pack_blocked();
      std::vector<uint32_t> bspec = spec;
      bspec.push_back(px);
      bspec.push_back(static_cast<uint32_t>(blocked_cob_ / 4));
      const Pipeline& pl = ctx_.pipeline("conv2d_blocked", bspec, sizeof(ConvPush));
      // One workgroup layer per batch item and block of blocked_cob_ channels: the shader's COB.
      const auto cob = static_cast<uint32_t>((cout_ + blocked_cob_ - 1) / blocked_cob_);
      cs.dispatch(pl, {bi.arg, {weight_blocked_.range(), Access::read}, {bias_blocked_.range(), Access::read}, br.arg, bo.arg},
                  p,
                  flat_groups(os.h * ((os.w + px - 1) / px), static_cast<uint32_t>(os.n) * cob),
                  info);
      return;
    }
    case ConvAlgo::direct: {
      pack_direct();
      const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
      const int64_t kk = static_cast<int64_t>(params_.kernel) * params_.kernel, cob = direct_cob_;
      const UniformSlabChunks ch = direct_chunks();
      const int64_t chunk = ch.chunk, blocks = (cout_ + cob - 1) / cob;
      const size_t slab_bytes = static_cast<size_t>(chunk * kk * cob) * 4;
      // A 1x1 stride-1 conv without padding is one row of H*W pixels per channel plane.
      const bool flat = params_.kernel == 1 && params_.stride == 1 && params_.pad == 0;
      ConvPush dp = p;
      if (flat) {
        dp.h = dp.oh = 1;
        dp.w = dp.ow = u32(is.h * is.w);
      }
      const int64_t px = direct_px_, py = flat ? 1 : direct_py_;
      const int64_t tasks = ((dp.oh + py - 1) / py) * ((dp.ow + px - 1) / px);
      const int64_t g = (tasks + 15) / 16, gx = std::min<int64_t>(g, 65535);
      const Groups groups{u32(gx), u32((g + gx - 1) / gx), u32(os.n)};
      if (chunk < cin_ && residual_overlaps_output())
        throw Error(name_ + ": the direct algorithm accumulates in the output, which overlaps the residual");
      const bool texel_input = direct_texel_input_ && bi.arg.range.size / 4 <= ctx_.info().max_texel_buffer_elements;
      for (int64_t b = 0; b < blocks; ++b)
        for (int64_t c0 = 0; c0 < cin_; c0 += chunk) {
          const bool first = c0 == 0, last = c0 + chunk >= cin_;
          std::vector<uint32_t> dspec = spec;
          dspec.insert(dspec.end(),
                       {direct_px_, u32(cob / 4), first ? 1u : 0u, last ? 1u : 0u, u32(chunk * kk * cob / 4), u32(py),
                        u32(cob == 4 ? std::min<int64_t>(4, cout_ - b * cob) : 4)});
          ConvPush cp = dp;
          cp.in_off = u32(bi.offset + c0 * is.h * is.w);
          cp.cin = u32(std::min(chunk, cin_ - c0));
          cp.pad = params_.pad;
          cp.co0 = u32(b * cob);
          const BufferRange wr = weight_direct_.range(static_cast<size_t>((b * ch.cin_pad + c0) * kk * cob) * 4, slab_bytes);
          cs.dispatch(ctx_.pipeline(texel_input ? "conv2d_direct_texel" : "conv2d_direct", dspec, sizeof(ConvPush)),
                      {bi.arg, {wr, Access::read}, {bias_.range(), Access::read}, br.arg,
                       {bo.arg.range, first ? Access::write : Access::read_write}},
                      cp, groups, dispatch_part(info, cp.cin, std::min(cob, cout_ - b * cob), cin_, cout_, blocks));
        }
      return;
    }
    case ConvAlgo::winograd: {
      if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
      const WinogradSizes wz = winograd_sizes(os);  // tiles of the output
      const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
      const int64_t cv = winograd_ks_ * winograd_ks_ * cin_, chunk = winograd_chunk(is);
      const bool s2 = params_.stride == 2;
      const Tensor& vt = workspace_->get(ctx_, 0, 36 * chunk * wz.tiles_pad);
      const Tensor& mt = workspace_->get(ctx_, 1, 36 * gemm_cout_pad_ * wz.tiles_pad);
      const BufferRange mr = mt.range(0, static_cast<size_t>(36 * gemm_cout_pad_ * wz.tiles_pad) * 4);
      // Input channels in chunks whose transformed tiles fit the scratch; the GEMM accumulates.
      for (int64_t c0 = 0; c0 < cv; c0 += chunk) {
        const int64_t cn = std::min(chunk, cv - c0);
        const BufferRange vr = vt.range(0, static_cast<size_t>(36 * cn * wz.tiles_pad) * 4);
        struct InPush {
          uint32_t in_off, in_bs, cin, h, w, tiles_x_pad, tiles_y, ngroups, tiles_pad, ks, c_begin, chunk, s_in, off_mul;
          int32_t off_base;
        } ip{bi.offset, bi.batch_stride, u32(cin_), u32(is.h), u32(is.w), u32(wz.tiles_x_pad), u32(wz.tiles_y),
             u32(wz.ngroups), u32(wz.tiles_pad), u32(winograd_ks_), u32(c0), u32(cn), s2 ? 2u : 1u, s2 ? 1u : 3u,
             params_.kernel == 5 ? -1 : 0};
        cs.dispatch(ctx_.pipeline("winograd_input", {}, sizeof ip), {bi.arg, {vr, Access::write}}, ip,
                    Groups{u32((wz.ngroups + 63) / 64), u32(cn), 1},
                    {info.name + "_wino_in", 0, 4.0 * 36.0 * (cn * wz.tiles_pad) * (1 + 16.0 / 36)});
        struct GemmPush {
          uint32_t chunk, tiles_pad, cout_pad, cin_total, c_begin;
        } gp{u32(cn), u32(wz.tiles_pad), u32(gemm_cout_pad_), u32(cv), u32(c0)};
        const uint32_t tv = gemm_tv_;
        cs.dispatch(ctx_.pipeline("winograd_gemm", {u32(gemm_cob_), c0 > 0 ? 1u : 0u, 36u, tv}, sizeof gp),
                    {{vr, Access::read}, {weight_winograd_.range(), Access::read},
                     {mr, c0 > 0 ? Access::read_write : Access::write}},
                    gp, flat_groups(36 * (gemm_cout_pad_ / gemm_cob_) * (wz.tiles_pad / (4 * tv)), 1),
                    {info.name + "_wino_gemm", info.flop * static_cast<double>(cn) / static_cast<double>(cv),
                     4.0 * 36 * (cn + gemm_cout_pad_ * (c0 > 0 ? 2 : 1)) * wz.tiles_pad});
      }
      struct OutPush {
        uint32_t res_off, res_bs, out_off, out_bs, cout, oh, ow, tiles_x_pad, tiles_y, ngroups, tiles_pad, cout_pad;
      } op{br.offset, br.batch_stride, bo.offset, bo.batch_stride, u32(cout_), u32(os.h), u32(os.w), u32(wz.tiles_x_pad),
           u32(wz.tiles_y), u32(wz.ngroups), u32(wz.tiles_pad), u32(gemm_cout_pad_)};
      cs.dispatch(ctx_.pipeline("winograd_output", {spec[2], spec[3], spec[4]}, sizeof op),
                  {{mr, Access::read}, {bias_.range(), Access::read}, br.arg, bo.arg}, op,
                  Groups{u32((wz.ngroups + 63) / 64), u32(cout_), 1},
                  {info.name + "_wino_out", 0, 4.0 * (36.0 * cout_ * wz.tiles_pad + static_cast<double>(os.count()))});
      return;
    }
    case ConvAlgo::gemm: {
      if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
      const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
      const int64_t pix_pad = gemm_pix_pad(is), npix = is.n * is.h * is.w, chunk = winograd_chunk(is);
      const Tensor& vt = workspace_->get(ctx_, 0, chunk * pix_pad);
      const Tensor& mt = workspace_->get(ctx_, 1, gemm_cout_pad_ * pix_pad);
      const BufferRange mr = mt.range(0, static_cast<size_t>(gemm_cout_pad_ * pix_pad) * 4);
      for (int64_t c0 = 0; c0 < cin_; c0 += chunk) {
        const int64_t cn = std::min(chunk, cin_ - c0);
        const BufferRange vr = vt.range(0, static_cast<size_t>(cn * pix_pad) * 4);
        struct PackPush {
          uint32_t in_off, in_bs, plane, npix, pix_pad, c_begin;
        } pp{bi.offset, bi.batch_stride, u32(is.h * is.w), u32(npix), u32(pix_pad), u32(c0)};
        cs.dispatch(ctx_.pipeline("conv1x1_pack", {}, sizeof pp), {bi.arg, {vr, Access::write}}, pp,
                    Groups{u32((pix_pad / 4 + 63) / 64), u32(cn), 1},
                    {info.name + "_gemm_pack", 0, 8.0 * static_cast<double>(cn * pix_pad)});
        struct GemmPush {
          uint32_t chunk, tiles_pad, cout_pad, cin_total, c_begin;
        } gp{u32(cn), u32(pix_pad), u32(gemm_cout_pad_), u32(cin_), u32(c0)};
        const uint32_t tv = gemm_tv_;
        cs.dispatch(ctx_.pipeline("winograd_gemm", {u32(gemm_cob_), c0 > 0 ? 1u : 0u, 1u, tv}, sizeof gp),
                    {{vr, Access::read}, {weight_gemm_.range(), Access::read},
                     {mr, c0 > 0 ? Access::read_write : Access::write}},
                    gp, flat_groups((gemm_cout_pad_ / gemm_cob_) * (pix_pad / (4 * tv)), 1),
                    {info.name + "_gemm", info.flop * static_cast<double>(cn) / static_cast<double>(cin_),
                     4.0 * (cn + gemm_cout_pad_ * (c0 > 0 ? 2 : 1)) * pix_pad});
      }
      struct OutPush {
        uint32_t res_off, res_bs, out_off, out_bs, plane, npix, pix_pad;
      } op{br.offset, br.batch_stride, bo.offset, bo.batch_stride, u32(is.h * is.w), u32(npix), u32(pix_pad)};
      cs.dispatch(ctx_.pipeline("conv1x1_output", {spec[2], spec[3], spec[4]}, sizeof op),
                  {{mr, Access::read}, {bias_.range(), Access::read}, br.arg, bo.arg}, op,
                  Groups{u32((pix_pad / 4 + 63) / 64), u32(cout_), 1},
                  {info.name + "_gemm_out", 0, 8.0 * static_cast<double>(os.count())});
      return;
    }
    default: break;
  }
  throw Error(name_ + ": algorithm " + std::string(conv_algo_name(algo)) + " is not implemented");
}

}  // namespace vkunroll
