#include "kernels/conv2d.hpp"

#include <cstring>

#include "runtime/context.hpp"
#include "runtime/pipeline.hpp"

namespace vkunroll {

namespace {
constexpr int64_t kBlockCo = 8;  // output channels per invocation in the blocked paths

struct ConvPush {
  uint32_t in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint32_t cin, h, w, cout, oh, ow, pad;
};

std::string conv_label(const std::string& name, const Conv2dParams& p) {
  return name + "_" + std::to_string(p.kernel) + "x" + std::to_string(p.kernel) +
         (p.stride != 1 ? "s" + std::to_string(p.stride) : "");
}
}  // namespace

const char* conv_algo_name(ConvAlgo a) {
  switch (a) {
    case ConvAlgo::automatic: return "automatic";
    case ConvAlgo::naive: return "naive";
    case ConvAlgo::blocked: return "blocked";
    case ConvAlgo::tiled: return "tiled";
    case ConvAlgo::winograd: return "winograd";
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

Conv2d::Conv2d(Context& ctx, const HostTensor& weight, const HostTensor& bias, const Conv2dParams& params,
               std::string name)
    : ctx_(ctx), name_(std::move(name)), params_(params) {
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

  weight_ = HostTensor(Shape{1, 1, 1, weight.shape.count()}, weight.data).to_device(ctx);
  bias_ = HostTensor(Shape{1, 1, 1, cout_}, b).to_device(ctx);
}

bool Conv2d::supports(ConvAlgo algo) const {
  switch (algo) {
    case ConvAlgo::automatic:
    case ConvAlgo::naive: return true;
    default: return false;
  }
}

ConvAlgo Conv2d::choose_algorithm(int64_t, int64_t) const { return ConvAlgo::naive; }

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
  if (algo == ConvAlgo::automatic) algo = choose_algorithm(is.h, is.w);
  if (!supports(algo))
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
      const Pipeline& pl = ctx_.pipeline("conv2d_naive", spec, sizeof(ConvPush));
      cs.dispatch(pl, {bi.arg, {weight_.range(), Access::read}, {bias_.range(), Access::read}, br.arg, bo.arg}, p,
                  Groups{static_cast<uint32_t>((os.w + 7) / 8), static_cast<uint32_t>((os.h + 7) / 8),
                         static_cast<uint32_t>(os.n * cout_)},
                  info);
      return;
    }
    default: break;
  }
  throw Error(name_ + ": algorithm " + std::string(conv_algo_name(algo)) + " is not implemented");
}

}  // namespace vkunroll
