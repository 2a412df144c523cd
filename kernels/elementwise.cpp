#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/kernels/elementwise.hpp"

#include <algorithm>

#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"

namespace vkunroll {

namespace {
enum Op : uint32_t { kCopy = 0, kAdd = 1, kScaleAct = 2, kBlend = 3, kClamp01 = 4 };
const char* kOpNames[] = {"copy", "add", "scale_act", "blend", "clamp01"};

struct EwPush {
  uint32_t a_off, a_bs, b_off, b_bs, m_off, m_bs, out_off, out_bs, c, plane;
  float scale;
};

template <class S>
void check_same(const std::string& op, const S& s, const Shape& expect, const char* what) {
  check_slice(s, op, what);
  if (s.shape() != expect) throw Error(op + ": " + what + " " + s.shape().str() + ", expected " + expect.str());
}

// copy between an f32 and an f16 slice.
void convert(CommandStream& cs, Slice in, Slice out) {
  const Shape s = in.shape();
  const BoundSlice bi = bind_slice(in, Access::read), bo = bind_slice(out, Access::write);
  struct {
    uint32_t in_off, in_bs, out_off, out_bs, c, plane;
  } p{bi.offset, bi.batch_stride, bo.offset, bo.batch_stride, static_cast<uint32_t>(s.c), static_cast<uint32_t>(s.plane())};
  Context& ctx = in.t->context();
  require_fp16(ctx, "copy");
  const bool to_f16 = out.t->dtype() == DType::f16;
  const double n = static_cast<double>(s.count());
  cs.dispatch(kernel_pipeline(ctx, to_f16 ? "convert_f32_to_f16" : "convert_f16_to_f32", {}, sizeof p), {bi.arg, bo.arg}, p,
              Groups{static_cast<uint32_t>((s.plane() + 63) / 64), static_cast<uint32_t>(s.c), static_cast<uint32_t>(s.n)},
              {"convert", 0, 6.0 * n});
}

void run(CommandStream& cs, Op op, Slice a, const Slice* b, const Slice* m, Slice out, Act act, float scale,
         const TexelReadOptions& opt) {
  const std::string name = kOpNames[op];
  check_slice(a, name, "input");
  const Shape s = a.shape();
  check_same(name, out, s, "output");
  if (b) check_same(name, *b, s, "second input");
  if (m) check_same(name, *m, Shape{s.n, 1, s.h, s.w}, "mask");
  if (op == kCopy && out.t->dtype() != a.t->dtype()) return convert(cs, a, out);
  // One precision for every operand (the fp16 variant stores all of them as float16).
  const Precision prec = slice_precision(a);
  check_precision(out, prec, name, "output");
  if (b) check_precision(*b, prec, name, "second input");
  if (m) check_precision(*m, prec, name, "mask");
  // The shader covers four elements an invocation in four steps, no loop: one grid row must hold a plane.
  const int64_t groups_x = (s.plane() + 255) / 256;
  if (groups_x > 65535)
    throw Error(name + ": a plane of " + std::to_string(s.plane()) + " values exceeds one dispatch's 65535 x 256");
  const double eb = static_cast<double>(dtype_size(precision_dtype(prec)));
  BoundSlice ba = bind_slice(a, Access::read);
  const BoundSlice bo = bind_slice(out, Access::write);
  BoundSlice bb = b ? bind_slice(*b, Access::read) : ba, bm = m ? bind_slice(*m, Access::read) : ba;
  EwPush p{ba.offset, ba.batch_stride, bb.offset, bb.batch_stride, bm.offset, bm.batch_stride, bo.offset,
           bo.batch_stride, static_cast<uint32_t>(s.c), static_cast<uint32_t>(s.plane()), scale};
  Context& ctx = a.t->context();
  const double n = static_cast<double>(s.count());
  const std::string shader = texel_read_shader(ctx, "elementwise", {&ba, &bb, &bm}, prec, opt);
  cs.dispatch(kernel_pipeline(ctx, shader_for(ctx, shader, prec, name), {op, static_cast<uint32_t>(act.kind), spec_float(act.slope)},
                              sizeof p),
              {ba.arg, bb.arg, bm.arg, bo.arg}, p,
              Groups{static_cast<uint32_t>(groups_x), static_cast<uint32_t>(s.c), static_cast<uint32_t>(s.n)},
              {name, (op == kCopy || op == kClamp01) ? 0 : (op == kBlend ? 3 : 1) * n,
               eb * n * (2 + (b ? 1 : 0)) + (m ? eb * static_cast<double>(s.n * s.plane()) : 0)});
}

template <class F>
void host_map(const std::string& op, HostSlice a, HostSliceOut out, F f) {
  check_slice(a, op, "input");
  check_same(op, HostSlice(out), a.shape(), "output");
  for (int64_t n = 0; n < a.batch(); ++n)
    for (int64_t c = 0; c < a.channels(); ++c)
      for (int64_t y = 0; y < a.height(); ++y)
        for (int64_t x = 0; x < a.width(); ++x) out.at(n, c, y, x) = f(n, c, y, x);
}
}  // namespace

void copy(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt) {
  run(cs, kCopy, in, nullptr, nullptr, out, {}, 1.f, opt);
}
void add(CommandStream& cs, Slice a, Slice b, Slice out, const TexelReadOptions& opt) {
  run(cs, kAdd, a, &b, nullptr, out, {}, 1.f, opt);
}
void scale_act(CommandStream& cs, Slice in, Slice out, Act act, float scale, const TexelReadOptions& opt) {
  run(cs, kScaleAct, in, nullptr, nullptr, out, act, scale, opt);
}
void blend(CommandStream& cs, Slice m, Slice a, Slice b, Slice out, const TexelReadOptions& opt) {
  run(cs, kBlend, a, &b, &m, out, {}, 1.f, opt);
}
void clamp01(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt) {
  run(cs, kClamp01, in, nullptr, nullptr, out, {}, 1.f, opt);
}

void copy_ref(HostSlice in, HostSliceOut out) {
  host_map("copy_ref", in, out, [&](int64_t n, int64_t c, int64_t y, int64_t x) { return in.at(n, c, y, x); });
}
void add_ref(HostSlice a, HostSlice b, HostSliceOut out) {
  check_same("add_ref", b, a.shape(), "second input");
  host_map("add_ref", a, out, [&](int64_t n, int64_t c, int64_t y, int64_t x) { return a.at(n, c, y, x) + b.at(n, c, y, x); });
}
void scale_act_ref(HostSlice in, HostSliceOut out, Act act, float scale) {
  host_map("scale_act_ref", in, out,
           [&](int64_t n, int64_t c, int64_t y, int64_t x) { return scale * apply_act(act, in.at(n, c, y, x)); });
}
void blend_ref(HostSlice m, HostSlice a, HostSlice b, HostSliceOut out) {
  check_same("blend_ref", b, a.shape(), "second input");
  check_same("blend_ref", m, Shape{a.batch(), 1, a.height(), a.width()}, "mask");
  host_map("blend_ref", a, out, [&](int64_t n, int64_t c, int64_t y, int64_t x) {
    const float mm = m.at(n, 0, y, x);
    return mm * a.at(n, c, y, x) + (1.f - mm) * b.at(n, c, y, x);
  });
}
void clamp01_ref(HostSlice in, HostSliceOut out) {
  host_map("clamp01_ref", in, out,
           [&](int64_t n, int64_t c, int64_t y, int64_t x) { return std::clamp(in.at(n, c, y, x), 0.f, 1.f); });
}

}  // namespace vkunroll
