#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"

#include <string>
#include <vector>

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {
struct PadPush {
  uint32_t in_off, in_bs, out_off, out_bs, c, h, w, oh, ow, top, left;
};

// `spec`: the shader's specialization constants (reflection_pad: REFLECT_ONCE).
void dispatch(CommandStream& cs, const std::string& op, Slice in, Slice out, int64_t top, int64_t left,
              const TexelReadOptions& opt, const std::vector<uint32_t>& spec = {}) {
  const Shape is = in.shape(), os = out.shape();
  BoundSlice bi = bind_slice(in, Access::read);
  const BoundSlice bo = bind_slice(out, Access::write);
  PadPush p{bi.offset, bi.batch_stride, bo.offset, bo.batch_stride, static_cast<uint32_t>(os.c),
            static_cast<uint32_t>(is.h), static_cast<uint32_t>(is.w), static_cast<uint32_t>(os.h),
            static_cast<uint32_t>(os.w), static_cast<uint32_t>(top), static_cast<uint32_t>(left)};
  Context& ctx = in.t->context();
  const Precision prec = slice_precision(in);
  check_precision(out, prec, op, "output");
  const std::string shader = texel_read_shader(ctx, op, {&bi}, prec, opt);
  // crop, crop_texel and reflection_pad_texel copy four pixels of a row per invocation.
  const int64_t per_row = shader != "reflection_pad" ? (os.w + 3) / 4 : os.w;
  cs.dispatch(kernel_pipeline(ctx, shader_for(ctx, shader, prec, shader), spec, sizeof p), {bi.arg, bo.arg}, p,
              Groups{static_cast<uint32_t>((os.h * per_row + 63) / 64), static_cast<uint32_t>(os.c),
                     static_cast<uint32_t>(os.n)},
              {shader, 0, 2.0 * static_cast<double>(dtype_size(in.t->dtype())) * static_cast<double>(os.count())});
}

template <class S, class O>
void check_pad(const std::string& op, const S& in, const O& out, const Pads& pads) {
  check_slice(in, op, "input");
  check_slice(out, op, "output");
  if (pads.top < 0 || pads.bottom < 0 || pads.left < 0 || pads.right < 0)
    throw Error(op + ": negative pads");
  const Shape is = in.shape();
  const Shape expect{is.n, is.c, is.h + pads.top + pads.bottom, is.w + pads.left + pads.right};
  if (out.shape() != expect) throw Error(op + ": output " + out.shape().str() + ", expected " + expect.str());
}

template <class S, class O>
void check_crop(const std::string& op, const S& in, const O& out, int64_t top, int64_t left) {
  check_slice(in, op, "input");
  check_slice(out, op, "output");
  const Shape is = in.shape(), os = out.shape();
  if (os.n != is.n || os.c != is.c || top < 0 || left < 0 || top + os.h > is.h || left + os.w > is.w)
    throw Error(op + ": a " + os.str() + " window at (" + std::to_string(top) + ", " + std::to_string(left) +
                ") does not fit the input " + is.str());
}
}  // namespace

Pads size_adapter_pads(int64_t h, int64_t w, int64_t multiple) {
  if (h <= 0 || w <= 0 || multiple <= 0)
    throw Error("size_adapter_pads: invalid size " + std::to_string(h) + "x" + std::to_string(w));
  const int64_t dh = (h + multiple - 1) / multiple * multiple - h, dw = (w + multiple - 1) / multiple * multiple - w;
  return {dh / 2, dh - dh / 2, dw / 2, dw - dw / 2};
}

int64_t reflect_index(int64_t i, int64_t size) {
  if (size == 1) return 0;
  const int64_t period = 2 * (size - 1);
  i %= period;
  if (i < 0) i += period;
  return i >= size ? period - i : i;
}

void reflection_pad(CommandStream& cs, Slice in, Slice out, const Pads& pads, const TexelReadOptions& opt) {
  check_pad("reflection_pad", in, out, pads);
  // One reflection per axis (reflect_index.glsl's REFLECT_ONCE) where every pad is below its axis.
  const Shape is = in.shape();
  const bool once = is.h > 1 && is.w > 1 && pads.top < is.h && pads.bottom < is.h && pads.left < is.w && pads.right < is.w;
  dispatch(cs, "reflection_pad", in, out, pads.top, pads.left, opt, {once ? 1u : 0u});
}

void reflection_pad_ref(HostSlice in, HostSliceOut out, const Pads& pads) {
  check_pad("reflection_pad_ref", in, HostSlice(out), pads);
  for (int64_t n = 0; n < out.batch(); ++n)
    for (int64_t c = 0; c < out.channels(); ++c)
      for (int64_t y = 0; y < out.height(); ++y)
        for (int64_t x = 0; x < out.width(); ++x)
          out.at(n, c, y, x) =
              in.at(n, c, reflect_index(y - pads.top, in.height()), reflect_index(x - pads.left, in.width()));
}

void crop(CommandStream& cs, Slice in, Slice out, int64_t top, int64_t left, const TexelReadOptions& opt) {
  check_crop("crop", in, out, top, left);
  dispatch(cs, "crop", in, out, top, left, opt);
}

void crop_ref(HostSlice in, HostSliceOut out, int64_t top, int64_t left) {
  check_crop("crop_ref", in, HostSlice(out), top, left);
  for (int64_t n = 0; n < out.batch(); ++n)
    for (int64_t c = 0; c < out.channels(); ++c)
      for (int64_t y = 0; y < out.height(); ++y)
        for (int64_t x = 0; x < out.width(); ++x) out.at(n, c, y, x) = in.at(n, c, y + top, x + left);
}

}  // namespace vkunroll
