#include "vkunroll/kernels/copy_rect.hpp"

#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {
struct CopyPush {
  uint32_t in_off, in_bs, out_off, out_bs, c, ih, iw, oh, ow, sy, sx, dy, dx, rh, rw;
};
struct FillPush {
  uint32_t out_off, out_bs, c, oh, ow, y0, x0, rh, rw;
  float value;
};

std::string rect_str(const Rect& r) {
  return std::to_string(r.h) + "x" + std::to_string(r.w) + " at (" + std::to_string(r.y) + ", " + std::to_string(r.x) + ")";
}
bool inside(const Rect& r, int64_t h, int64_t w) {
  return r.y >= 0 && r.x >= 0 && r.h >= 0 && r.w >= 0 && r.y + r.h <= h && r.x + r.w <= w;
}

template <class S, class O>
void check_copy(const std::string& op, const S& in, const O& out, const Rect& src, int64_t dy, int64_t dx) {
  check_slice(in, op, "input");
  check_slice(out, op, "output");
  const Shape is = in.shape(), os = out.shape();
  if (is.n != os.n || is.c != os.c)
    throw Error(op + ": input " + is.str() + " and output " + os.str() + " differ in batch or channels");
  if (!inside(src, is.h, is.w)) throw Error(op + ": source rectangle " + rect_str(src) + " is not inside the input " + is.str());
  const Rect dst{dy, dx, src.h, src.w};
  if (!inside(dst, os.h, os.w))
    throw Error(op + ": destination rectangle " + rect_str(dst) + " is not inside the output " + os.str());
}
template <class O>
void check_fill(const std::string& op, const O& out, const Rect& r) {
  check_slice(out, op, "output");
  if (!inside(r, out.shape().h, out.shape().w))
    throw Error(op + ": rectangle " + rect_str(r) + " is not inside the output " + out.shape().str());
}
uint32_t u32(int64_t v) { return static_cast<uint32_t>(v); }
}  // namespace

void copy_rect(CommandStream& cs, Slice in, Slice out, const Rect& src, int64_t dst_y, int64_t dst_x) {
  check_copy("copy_rect", in, out, src, dst_y, dst_x);
  if (src.area() == 0) return;
  const Shape is = in.shape(), os = out.shape();
  const Precision prec = slice_precision(in);
  check_precision(out, prec, "copy_rect", "output");
  Context& ctx = in.t->context();
  const BoundSlice bi = bind_slice(in, Access::read), bo = bind_slice(out, Access::write);
  const CopyPush p{bi.offset, bi.batch_stride, bo.offset, bo.batch_stride, u32(os.c), u32(is.h), u32(is.w), u32(os.h),
                   u32(os.w), u32(src.y), u32(src.x), u32(dst_y), u32(dst_x), u32(src.h), u32(src.w)};
  cs.dispatch(kernel_pipeline(ctx, shader_for(ctx, "copy_rect", prec, "copy_rect"), {}, sizeof p), {bi.arg, bo.arg}, p,
              Groups{u32((src.area() + 63) / 64), u32(os.c), u32(os.n)},
              {"copy_rect", 0, 2.0 * static_cast<double>(dtype_size(in.t->dtype())) * static_cast<double>(src.area() * os.c * os.n)});
}

void copy_rect_ref(HostSlice in, HostSliceOut out, const Rect& src, int64_t dst_y, int64_t dst_x) {
  check_copy("copy_rect_ref", in, HostSlice(out), src, dst_y, dst_x);
  for (int64_t n = 0; n < out.batch(); ++n)
    for (int64_t c = 0; c < out.channels(); ++c)
      for (int64_t y = 0; y < src.h; ++y)
        for (int64_t x = 0; x < src.w; ++x) out.at(n, c, dst_y + y, dst_x + x) = in.at(n, c, src.y + y, src.x + x);
}

void fill_rect(CommandStream& cs, Slice out, const Rect& r, float value) {
  check_fill("fill_rect", out, r);
  if (r.area() == 0) return;
  const Shape os = out.shape();
  const Precision prec = slice_precision(out);
  Context& ctx = out.t->context();
  const BoundSlice bo = bind_slice(out, Access::write);
  const FillPush p{bo.offset, bo.batch_stride, u32(os.c), u32(os.h), u32(os.w), u32(r.y), u32(r.x), u32(r.h), u32(r.w), value};
  cs.dispatch(kernel_pipeline(ctx, shader_for(ctx, "fill_rect", prec, "fill_rect"), {}, sizeof p), {bo.arg}, p,
              Groups{u32((r.area() + 63) / 64), u32(os.c), u32(os.n)},
              {"fill_rect", 0, static_cast<double>(dtype_size(out.t->dtype())) * static_cast<double>(r.area() * os.c * os.n)});
}

void fill_rect_ref(HostSliceOut out, const Rect& r, float value) {
  check_fill("fill_rect_ref", HostSlice(out), r);
  for (int64_t n = 0; n < out.batch(); ++n)
    for (int64_t c = 0; c < out.channels(); ++c)
      for (int64_t y = 0; y < r.h; ++y)
        for (int64_t x = 0; x < r.w; ++x) out.at(n, c, r.y + y, r.x + x) = value;
}

}  // namespace vkunroll
