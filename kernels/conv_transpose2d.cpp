#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/kernels/conv2d.hpp"

#include <algorithm>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
struct ConvTPush {
  uint32_t in_off, in_bs, out_off, out_bs;
  uint32_t cin, h, w, cout, oh, ow, pad;
  uint32_t co0 = 0;  // direct: first output channel of the dispatch
};
}  // namespace

const char* conv_transpose_algo_name(ConvTransposeAlgo a) {
  switch (a) {
    case ConvTransposeAlgo::automatic: return "automatic";
    case ConvTransposeAlgo::naive: return "naive";
    case ConvTransposeAlgo::blocked: return "blocked";
    case ConvTransposeAlgo::direct: return "direct";
    case ConvTransposeAlgo::igemm: return "igemm";
  }
  return "unknown";
}

int64_t conv_transpose_output_size(int64_t in, int kernel, int stride, int pad) {
  return (in - 1) * stride - 2 * pad + kernel;
}

void conv_transpose2d_ref(HostSlice in, HostSliceOut out, const HostTensor& weight, const HostTensor& bias,
                          const ConvTranspose2dParams& p) {
  check_slice(in, "conv_transpose2d_ref", "input");
  check_slice(HostSlice(out), "conv_transpose2d_ref", "output");
  const int64_t cin = in.channels(), cout = out.channels(), k = p.kernel;
  if (weight.shape != Shape{cin, cout, k, k})
    throw Error("conv_transpose2d_ref: weight " + weight.shape.str() + ", expected " + Shape{cin, cout, k, k}.str());
  const int64_t oh = conv_transpose_output_size(in.height(), p.kernel, p.stride, p.pad);
  const int64_t ow = conv_transpose_output_size(in.width(), p.kernel, p.stride, p.pad);
  if (out.height() != oh || out.width() != ow || out.batch() != in.batch())
    throw Error("conv_transpose2d_ref: output " + out.shape().str() + ", expected " +
                Shape{in.batch(), cout, oh, ow}.str());
  // Scatter form (the definition): every input value adds weight x value to k x k outputs.
  std::vector<double> acc(static_cast<size_t>(cout * oh * ow));
  for (int64_t n = 0; n < in.batch(); ++n) {
    for (int64_t co = 0; co < cout; ++co)
      for (int64_t i = 0; i < oh * ow; ++i)
        acc[static_cast<size_t>(co * oh * ow + i)] = bias.data.empty() ? 0.0 : bias.data[static_cast<size_t>(co)];
    for (int64_t ci = 0; ci < cin; ++ci)
      for (int64_t iy = 0; iy < in.height(); ++iy)
        for (int64_t ix = 0; ix < in.width(); ++ix) {
          const double v = in.at(n, ci, iy, ix);
          for (int64_t co = 0; co < cout; ++co)
            for (int64_t ky = 0; ky < k; ++ky) {
              const int64_t oy = iy * p.stride - p.pad + ky;
              if (oy < 0 || oy >= oh) continue;
              for (int64_t kx = 0; kx < k; ++kx) {
                const int64_t ox = ix * p.stride - p.pad + kx;
                if (ox < 0 || ox >= ow) continue;
                acc[static_cast<size_t>((co * oh + oy) * ow + ox)] += v * weight.at(ci, co, ky, kx);
              }
            }
        }
    for (int64_t co = 0; co < cout; ++co)
      for (int64_t oy = 0; oy < oh; ++oy)
        for (int64_t ox = 0; ox < ow; ++ox)
          out.at(n, co, oy, ox) = apply_act(p.act, static_cast<float>(acc[static_cast<size_t>((co * oh + oy) * ow + ox)]));
  }
}

ConvTranspose2d::ConvTranspose2d(Context& ctx, const HostTensor& weight, const HostTensor& bias,
                                 const ConvTranspose2dParams& params, std::string name, const ConvOptions& options)
    : ctx_(ctx), name_(std::move(name)), params_(params), precision_(options.precision) {
  options.validate(name_);
  if (precision_ == Precision::fp16) require_fp16(ctx, name_);
  const int k = params.kernel;
  if (k < 1 || params.stride < 1 || params.pad < 0 || params.pad >= k)
    throw Error(name_ + ": invalid kernel " + std::to_string(k) + " stride " + std::to_string(params.stride) +
                " pad " + std::to_string(params.pad));
  if (weight.shape.h != k || weight.shape.w != k || static_cast<int64_t>(weight.data.size()) != weight.shape.count())
    throw Error(name_ + ": weight " + weight.shape.str() + " is not [cin, cout, " + std::to_string(k) + ", " +
                std::to_string(k) + "] (PyTorch ConvTranspose2d layout)");
  cin_ = weight.shape.n;
  cout_ = weight.shape.c;
  if (!bias.data.empty() && static_cast<int64_t>(bias.data.size()) != cout_)
    throw Error(name_ + ": bias has " + std::to_string(bias.data.size()) + " values, " + std::to_string(cout_) +
                " output channels expected");
  std::vector<float> b = bias.data.empty() ? std::vector<float>(static_cast<size_t>(cout_), 0.f) : bias.data;
  weight_ = upload_weights(ctx, weight.data, precision_, name_);
  bias_ = to_device(ctx, HostTensor(Shape{1, 1, 1, cout_}, b));
  weight_host_ = weight;  // for the packings uploaded on first use (direct, igemm)
  gpu_family_ = options.gpu_family;
  if (k == 4 && params.stride == 2 && params.pad == 1) {
    // 32 channels per invocation where they divide cout: 3-6% faster than 16 on lavapipe (fewer
    // input loads per FMA), even on 512->256 where the chunks halve.
    direct_cob_ = cout_ <= 4 ? 4 : (cout_ <= 8 ? 8 : (cout_ % 32 == 0 ? 32 : 16));
    if (options.direct_cob) direct_cob_ = options.direct_cob;
    // Blocked layout [cout/8][cin][4][4][8], output channels zero-padded to a multiple of 8.
    const int64_t cob = (cout_ + 7) / 8;
    std::vector<float> wb(static_cast<size_t>(cob * cin_ * 16 * 8), 0.f), bb(static_cast<size_t>(cob * 8), 0.f);
    for (int64_t co = 0; co < cout_; ++co) {
      bb[static_cast<size_t>(co)] = b[static_cast<size_t>(co)];
      for (int64_t ci = 0; ci < cin_; ++ci)
        for (int64_t t = 0; t < 16; ++t)
          wb[static_cast<size_t>((((co / 8) * cin_ + ci) * 16 + t) * 8 + co % 8)] =
              weight.data[static_cast<size_t>((ci * cout_ + co) * 16 + t)];
    }
    weight_blocked_ = upload_weights(ctx, wb, precision_, name_);
    bias_blocked_ = to_device(ctx, HostTensor(Shape{1, 1, 1, static_cast<int64_t>(bb.size())}, bb));
  }
}

UniformSlabChunks ConvTranspose2d::direct_chunks() const {
  const int64_t e = static_cast<int64_t>(dtype_size(precision_dtype(precision_)));
  return uniform_slab_chunks(ctx_.info(), cin_, 16 * direct_cob_ * e, direct_chunk_limit_);
}

void ConvTranspose2d::pack_direct() const {
  if (!weight_direct_.empty()) return;
  // [cout/COB][cin][16][COB] plus one chunk of zeros, so every dispatch binds a whole slab.
  const int64_t cob = direct_cob_, blocks = (cout_ + cob - 1) / cob;
  const UniformSlabChunks ch = direct_chunks();
  const int64_t cin_pad = ch.cin_pad;  // aligned chunk starts
  // + 8 values: an fp16 slab is bound in whole 16-byte entries (8 halves), possibly 8 bytes past its end.
  std::vector<float> wd(static_cast<size_t>((blocks * cin_pad + ch.max) * 16 * cob + 8), 0.f);
  for (int64_t co = 0; co < cout_; ++co)
    for (int64_t ci = 0; ci < cin_; ++ci)
      for (int64_t t = 0; t < 16; ++t)
        wd[static_cast<size_t>((((co / cob) * cin_pad + ci) * 16 + t) * cob + co % cob)] =
            weight_host_.data[static_cast<size_t>((ci * cout_ + co) * 16 + t)];
  weight_direct_ = upload_weights(ctx_, wd, precision_, name_);
}

bool ConvTranspose2d::supports(ConvTransposeAlgo algo) const {
  if (algo == ConvTransposeAlgo::blocked) return !weight_blocked_.empty();
  if (algo == ConvTransposeAlgo::direct) return !weight_blocked_.empty() && direct_cob_ % 4 == 0 && direct_chunks().max >= 1;
  if (algo == ConvTransposeAlgo::igemm)
    return params_.kernel % params_.stride == 0 && params_.pad < params_.kernel;
  return algo == ConvTransposeAlgo::automatic || algo == ConvTransposeAlgo::naive;
}

std::vector<ConvTransposeAlgo> ConvTranspose2d::candidates() const {
  std::vector<ConvTransposeAlgo> out;
  for (uint32_t v = static_cast<uint32_t>(ConvTransposeAlgo::naive) + 1; v < 32; ++v) {
    const auto a = static_cast<ConvTransposeAlgo>(v);
    if (std::string(conv_transpose_algo_name(a)) != "unknown" && supports(a)) out.push_back(a);
  }
  return out;
}

ConvTransposeAlgo ConvTranspose2d::gpu_choice() const {
  // The igemm family, one dispatch for all the phases (blocked was the H100's best, 2026-11).
  if (supports(ConvTransposeAlgo::igemm)) return ConvTransposeAlgo::igemm;
  return supports(ConvTransposeAlgo::blocked) ? ConvTransposeAlgo::blocked : ConvTransposeAlgo::naive;
}

ConvTransposeAlgo ConvTranspose2d::choose_algorithm(int64_t, int64_t) const {
  if (ctx_.info().type != VK_PHYSICAL_DEVICE_TYPE_CPU || gpu_family_) return gpu_choice();
  // direct (weights from a uniform buffer, 16 or 32 channels per invocation) measured 5-10% faster than
  // blocked on every transposed conv of the model on lavapipe.
  // On a GPU `blocked` is 4-45x faster than `direct` (H100, docs/gpu_nvidia.md): direct is for llvmpipe.
  if (supports(ConvTransposeAlgo::direct) && ctx_.info().type == VK_PHYSICAL_DEVICE_TYPE_CPU)
    return ConvTransposeAlgo::direct;
  return supports(ConvTransposeAlgo::blocked) ? ConvTransposeAlgo::blocked : ConvTransposeAlgo::naive;
}

Shape ConvTranspose2d::output_shape(const Shape& in) const {
  return {in.n, cout_, conv_transpose_output_size(in.h, params_.kernel, params_.stride, params_.pad),
          conv_transpose_output_size(in.w, params_.kernel, params_.stride, params_.pad)};
}

double ConvTranspose2d::flop(const Shape& in) const {
  return 2.0 * static_cast<double>(in.n * in.h * in.w) * static_cast<double>(cin_ * cout_) * params_.kernel *
         params_.kernel;
}

void ConvTranspose2d::record(CommandStream& cs, Slice in, Slice out, ConvTransposeAlgo algo) const {
  check_slice(in, name_, "input");
  check_slice(out, name_, "output");
  check_precision(in, precision_, name_, "input");
  check_precision(out, precision_, name_, "output");
  const Shape is = in.shape(), os = out.shape(), expect = output_shape(is);
  if (is.c != cin_)
    throw Error(name_ + ": input has " + std::to_string(is.c) + " channels, the weights expect " + std::to_string(cin_));
  if (expect.h <= 0 || expect.w <= 0) throw Error(name_ + ": input " + is.str() + " gives an empty output");
  if (os != expect) throw Error(name_ + ": output slice " + os.str() + ", expected " + expect.str());
  if (algo == ConvTransposeAlgo::automatic) algo = choose_algorithm(is.h, is.w);
  if (!supports(algo))
    throw Error(name_ + ": algorithm " + std::string(conv_transpose_algo_name(algo)) + " does not apply");
  const BoundSlice bi = bind_slice(in, Access::read), bo = bind_slice(out, Access::write);
  ConvTPush p{bi.offset, bi.batch_stride, bo.offset, bo.batch_stride, static_cast<uint32_t>(cin_),
              static_cast<uint32_t>(is.h), static_cast<uint32_t>(is.w), static_cast<uint32_t>(cout_),
              static_cast<uint32_t>(os.h), static_cast<uint32_t>(os.w), static_cast<uint32_t>(params_.pad)};
  const std::vector<uint32_t> spec{static_cast<uint32_t>(params_.kernel), static_cast<uint32_t>(params_.stride),
                                   static_cast<uint32_t>(params_.act.kind), spec_float(params_.act.slope)};
  const int64_t e = static_cast<int64_t>(dtype_size(precision_dtype(precision_)));
  const auto shader = [&](const char* base) { return shader_for(ctx_, base, precision_, name_); };
  const double bytes = static_cast<double>(e) * (static_cast<double>(is.count() + os.count()) +
                                                 static_cast<double>(cin_ * cout_ * params_.kernel * params_.kernel));
  const DispatchInfo info{name_ + "_" + std::to_string(params_.kernel) + "x" + std::to_string(params_.kernel), flop(is),
                          bytes};
  if (algo == ConvTransposeAlgo::naive) {
    cs.dispatch(kernel_pipeline(ctx_, shader("conv_transpose2d_naive"), spec, sizeof(ConvTPush)),
                {bi.arg, {weight_.range(), Access::read}, {bias_.range(), Access::read}, bo.arg}, p,
                Groups{static_cast<uint32_t>((os.w + 7) / 8), static_cast<uint32_t>((os.h + 7) / 8),
                       static_cast<uint32_t>(os.n * cout_)},
                info);
    return;
  }
  if (algo == ConvTransposeAlgo::blocked) {
    const auto half_w = static_cast<uint32_t>((os.w + 1) / 2);
    cs.dispatch(kernel_pipeline(ctx_, shader("conv_transpose2d_blocked"), {spec[2], spec[3]}, sizeof(ConvTPush)),
                {bi.arg, {weight_blocked_.range(), Access::read}, {bias_blocked_.range(), Access::read}, bo.arg}, p,
                flat_groups(os.h * 2 * ((half_w + 7) / 8), static_cast<uint32_t>(os.n * ((cout_ + 7) / 8))),
                info);
    return;
  }
  if (algo == ConvTransposeAlgo::direct) {
    pack_direct();
    const auto u32 = [](int64_t v) { return static_cast<uint32_t>(v); };
    const int64_t cob = direct_cob_, blocks = (cout_ + cob - 1) / cob, px = 8;
    const UniformSlabChunks ch = direct_chunks();
    const int64_t chunk = ch.chunk;
    const int64_t half_w = (os.w + 1) / 2, tasks = os.h * 2 * ((half_w + px - 1) / px);
    const int64_t g = (tasks + 15) / 16, gx = std::min<int64_t>(g, 65535);
    const Groups groups{u32(gx), u32((g + gx - 1) / gx), u32(os.n)};
    const bool texel_input =
        texel_fetch_ && texel_view_fits(ctx_.info(), bi.arg.range.size, static_cast<uint64_t>(e));
    Arg input = bi.arg;
    if (precision_ == Precision::fp16) input.texel_format = VK_FORMAT_R16_SFLOAT;
    // The slab in whole 16-byte uniform entries (vec4s in fp32, 8 halves each in fp16).
    const int64_t slab_entries = (chunk * 16 * cob * e + 15) / 16;
    for (int64_t b = 0; b < blocks; ++b)
      for (int64_t c0 = 0; c0 < cin_; c0 += chunk) {
        const bool first = c0 == 0, last = c0 + chunk >= cin_;
        ConvTPush cp = p;
        cp.in_off = u32(bi.offset + c0 * is.h * is.w);
        cp.cin = u32(std::min(chunk, cin_ - c0));
        cp.co0 = u32(b * cob);
        const BufferRange wr = weight_direct_.range(static_cast<size_t>((b * ch.cin_pad + c0) * 16 * cob * e),
                                                    static_cast<size_t>(slab_entries) * 16);
        cs.dispatch(kernel_pipeline(ctx_, shader(texel_input ? "conv_transpose2d_direct_texel" : "conv_transpose2d_direct"),
                                  {spec[2], spec[3], u32(px), u32(cob / 4), first ? 1u : 0u, last ? 1u : 0u,
                                   u32(slab_entries)},
                                  sizeof(ConvTPush)),
                    {input, {wr, Access::read}, {bias_.range(), Access::read},
                     {bo.arg.range, first ? Access::write : Access::read_write}},
                    cp, groups, dispatch_part(info, cp.cin, std::min(cob, cout_ - b * cob), cin_, cout_, blocks));
      }
    return;
  }
  if (algo == ConvTransposeAlgo::igemm) return record_igemm(cs, bi, bo, is, info);
  throw Error(name_ + ": algorithm " + std::string(conv_transpose_algo_name(algo)) + " is not implemented");
}

IgemmProblem ConvTranspose2d::igemm_problem(const Shape& in) const {
  const Shape os = output_shape(in);
  IgemmProblem pb;
  pb.kh = pb.kw = static_cast<uint32_t>(params_.kernel / params_.stride);
  pb.stride = static_cast<uint32_t>(params_.stride);
  pb.pad = static_cast<uint32_t>(params_.pad);
  pb.transposed = true;
  pb.cin = cin_;
  pb.cout = cout_;
  pb.in = in;
  pb.out = os;
  pb.gh = (os.h + params_.stride - 1) / params_.stride;  // a phase's rows (the last phases may have one fewer)
  pb.gw = (os.w + params_.stride - 1) / params_.stride;
  pb.act = params_.act;
  pb.precision = precision_;
  return pb;
}

IgemmTile ConvTranspose2d::igemm_tile() const {
  // The UNets' deconvs halve the channels (2c -> c, c from 8 to 256): the tile whose channel side fits.
  if (cout_ <= 16) return {16, 128, 16, 4, 4};
  if (cout_ <= 32) return {32, 64, 16, 4, 4};
  return {64, 64, 16, 4, 4};
}

void ConvTranspose2d::record_igemm(CommandStream& cs, const BoundSlice& in, const BoundSlice& out, const Shape& is,
                                   const DispatchInfo& info) const {
  if (!workspace_) workspace_ = std::make_shared<ConvWorkspace>();
  const int s = params_.stride, j = params_.kernel / s, k = params_.kernel;
  if (weight_igemm_.empty()) {
    // Phase (py, px), sub-kernel tap (jy, jx) is the transposed kernel's tap ((py + pad) % s + s (j - 1 - jy), ...):
    // the taps that reach that phase, flipped to the stride-1 conv's order (shaders/conv2d_igemm.comp).
    const std::vector<float>& w = weight_host_.data;  // [cin][cout][k][k]
    weight_igemm_ = upload_weights(ctx_, igemm_pack(int64_t(s) * s, cin_, j * j, cout_, [&](int64_t ph, int64_t ci, int64_t tap, int64_t co) {
      const int64_t py = ph / s, px = ph % s, jy = tap / j, jx = tap % j;
      const int64_t ky = (py + params_.pad) % s + s * (j - 1 - jy), kx = (px + params_.pad) % s + s * (j - 1 - jx);
      return w[static_cast<size_t>(((ci * cout_ + co) * k + ky) * k + kx)];
    }), precision_, name_);
  }
  const IgemmProblem pb = igemm_problem(is);
  const IgemmTile tile = igemm_tile();
  const uint32_t splits = igemm_splits(ctx_.info(), tile, pb, ctx_.info().max_storage_buffer_range, igemm_splits_forced_);
  const IgemmBindings b{in, out, {{bias_.range(), Access::read}, 0, 0}, false, {weight_igemm_.range(), Access::read},
                        {bias_.range(), Access::read}};
  DispatchInfo named = info;
  named.name += "_igemm";
  igemm_record(ctx_, cs, *workspace_, tile, pb, b, splits, named);
}

ConvCost ConvTranspose2d::cost(ConvTransposeAlgo algo, const Shape& in) const {
  if (algo == ConvTransposeAlgo::automatic) algo = choose_algorithm(in.h, in.w);
  if (algo == ConvTransposeAlgo::igemm) {
    const IgemmProblem pb = igemm_problem(in);
    return igemm_cost(igemm_tile(), pb, igemm_splits(ctx_.info(), igemm_tile(), pb, ctx_.info().max_storage_buffer_range,
                                                      igemm_splits_forced_));
  }
  const double e = static_cast<double>(dtype_size(precision_dtype(precision_)));
  ConvCost c;  // no shared-memory tiles: each output reads its taps' inputs and weights once
  c.fma = flop(in) / 2;
  c.global_bytes = e * (static_cast<double>(in.count() + output_shape(in).count()) +
                        static_cast<double>(cin_ * cout_ * params_.kernel * params_.kernel));
  return c;
}

}  // namespace vkunroll
