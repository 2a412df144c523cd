#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/backward_warp.hpp"

#include <algorithm>
#include <cmath>

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {
struct WarpPush {
  uint32_t img_off, img_bs, flow_off, flow_bs, out_off, out_bs, c, h, w;
};

template <class S, class O>
void check(const std::string& op, const S& image, const S& flow, const O& out) {
  check_slice(image, op, "image");
  check_slice(flow, op, "flow");
  check_slice(out, op, "output");
  const Shape is = image.shape(), fs = flow.shape();
  if (fs != Shape{is.n, 2, is.h, is.w})
    throw Error(op + ": flow " + fs.str() + ", expected " + Shape{is.n, 2, is.h, is.w}.str() + " for image " + is.str());
  if (out.shape() != is) throw Error(op + ": output " + out.shape().str() + ", expected " + is.str());
}
}  // namespace

void backward_warp(CommandStream& cs, Slice image, Slice flow, Slice out) {
  check("backward_warp", image, flow, out);
  const Shape is = image.shape();
  const BoundSlice bi = bind_slice(image, Access::read), bf = bind_slice(flow, Access::read),
                   bo = bind_slice(out, Access::write);
  WarpPush p{bi.offset, bi.batch_stride, bf.offset, bf.batch_stride, bo.offset, bo.batch_stride,
             static_cast<uint32_t>(is.c), static_cast<uint32_t>(is.h), static_cast<uint32_t>(is.w)};
  Context& ctx = image.t->context();
  const Precision prec = slice_precision(image);
  check_precision(flow, prec, "backward_warp", "flow");
  check_precision(out, prec, "backward_warp", "output");
  cs.dispatch(kernel_pipeline(ctx, shader_for(ctx, "backward_warp", prec, "backward_warp"), {}, sizeof p), {bi.arg, bf.arg, bo.arg}, p,
              Groups{static_cast<uint32_t>((is.h * is.w + 63) / 64), 1, static_cast<uint32_t>(is.n)},
              {"backward_warp", 0,
               static_cast<double>(dtype_size(image.t->dtype())) * static_cast<double>(is.n * is.plane() * (5 * is.c + 2))});
}

void backward_warp_ref(HostSlice image, HostSlice flow, HostSliceOut out) {
  check("backward_warp_ref", image, flow, HostSlice(out));
  const int64_t h = image.height(), w = image.width();
  for (int64_t n = 0; n < image.batch(); ++n)
    for (int64_t y = 0; y < h; ++y)
      for (int64_t x = 0; x < w; ++x) {
        double sx = static_cast<double>(x) + flow.at(n, 0, y, x), sy = static_cast<double>(y) + flow.at(n, 1, y, x);
        sx = std::isnan(sx) ? 0.0 : std::clamp(sx, 0.0, static_cast<double>(w - 1));
        sy = std::isnan(sy) ? 0.0 : std::clamp(sy, 0.0, static_cast<double>(h - 1));
        const int64_t x0 = static_cast<int64_t>(std::floor(sx)), y0 = static_cast<int64_t>(std::floor(sy));
        const int64_t x1 = std::min(x0 + 1, w - 1), y1 = std::min(y0 + 1, h - 1);
        const double ax = sx - static_cast<double>(x0), ay = sy - static_cast<double>(y0);
        for (int64_t c = 0; c < image.channels(); ++c) {
          const double v = (image.at(n, c, y0, x0) * (1 - ax) + image.at(n, c, y0, x1) * ax) * (1 - ay) +
                           (image.at(n, c, y1, x0) * (1 - ax) + image.at(n, c, y1, x1) * ax) * ay;
          out.at(n, c, y, x) = static_cast<float>(v);
        }
      }
}

}  // namespace vkunroll
