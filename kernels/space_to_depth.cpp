#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {
struct S2DPush {
  uint32_t in_off, in_bs, out_off, out_bs, c_out, h, w, oh, ow;
};

template <class S>
void check_shapes(const std::string& op, const S& in, const Shape& out, const Shape& expect) {
  check_slice(in, op, "input");
  if (out != expect) throw Error(op + ": output " + out.str() + ", expected " + expect.str() + " for input " + in.shape().str());
}

void dispatch(CommandStream& cs, const std::string& op, Slice in, Slice out, const TexelReadOptions& opt) {
  const Shape is = in.shape(), os = out.shape();
  BoundSlice bi = bind_slice(in, Access::read);
  const BoundSlice bo = bind_slice(out, Access::write);
  S2DPush p{bi.offset, bi.batch_stride, bo.offset, bo.batch_stride, static_cast<uint32_t>(os.c),
            static_cast<uint32_t>(is.h), static_cast<uint32_t>(is.w), static_cast<uint32_t>(os.h),
            static_cast<uint32_t>(os.w)};
  Context& ctx = in.t->context();
  const Precision prec = slice_precision(in);
  check_precision(out, prec, op, "output");
  const std::string shader = texel_read_shader(ctx, op, {&bi}, prec, opt);
  // The texel forms write four values of an output row per invocation.
  const int64_t per_row = shader != op ? (os.w + 3) / 4 : os.w;
  cs.dispatch(kernel_pipeline(ctx, shader_for(ctx, shader, prec, shader), {}, sizeof p), {bi.arg, bo.arg}, p,
              Groups{static_cast<uint32_t>((os.h * per_row + 63) / 64), static_cast<uint32_t>(os.c),
                     static_cast<uint32_t>(os.n)},
              {shader, 0, 2.0 * static_cast<double>(dtype_size(in.t->dtype())) * static_cast<double>(os.count())});
}
}  // namespace

Shape space_to_depth_shape(const Shape& in) { return {in.n, in.c * 4, (in.h + 1) / 2, (in.w + 1) / 2}; }

Shape depth_to_space_shape(const Shape& in) {
  if (in.c % 4 != 0) throw Error("depth_to_space: " + std::to_string(in.c) + " channels is not a multiple of 4");
  return {in.n, in.c / 4, in.h * 2, in.w * 2};
}

void space_to_depth(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt) {
  check_slice(out, "space_to_depth", "output");
  check_shapes("space_to_depth", in, out.shape(), space_to_depth_shape(in.shape()));
  dispatch(cs, "space_to_depth", in, out, opt);
}

void depth_to_space(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt) {
  check_slice(out, "depth_to_space", "output");
  check_shapes("depth_to_space", in, out.shape(), depth_to_space_shape(in.shape()));
  dispatch(cs, "depth_to_space", in, out, opt);
}

void space_to_depth_ref(HostSlice in, HostSliceOut out) {
  check_shapes("space_to_depth_ref", in, out.shape(), space_to_depth_shape(in.shape()));
  for (int64_t n = 0; n < in.batch(); ++n)
    for (int64_t c = 0; c < in.channels(); ++c)
      for (int64_t i = 0; i < 2; ++i)
        for (int64_t j = 0; j < 2; ++j)
          for (int64_t y = 0; y < out.height(); ++y)
            for (int64_t x = 0; x < out.width(); ++x) {
              const int64_t iy = 2 * y + i, ix = 2 * x + j;
              out.at(n, c * 4 + i * 2 + j, y, x) = (iy < in.height() && ix < in.width()) ? in.at(n, c, iy, ix) : 0.f;
            }
}

void depth_to_space_ref(HostSlice in, HostSliceOut out) {
  check_shapes("depth_to_space_ref", in, out.shape(), depth_to_space_shape(in.shape()));
  for (int64_t n = 0; n < out.batch(); ++n)
    for (int64_t c = 0; c < out.channels(); ++c)
      for (int64_t y = 0; y < out.height(); ++y)
        for (int64_t x = 0; x < out.width(); ++x)
          out.at(n, c, y, x) = in.at(n, c * 4 + (y % 2) * 2 + (x % 2), y / 2, x / 2);
}

}  // namespace vkunroll
