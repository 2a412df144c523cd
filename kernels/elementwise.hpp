// Elementwise ops on slices (operands may be different channel ranges or batch items of one
// tensor). The output may be the same slice as an input (in place); it must not partly overlap one.
#pragma once
#include "vkunroll/kernels/common.hpp"

namespace vkunroll {

// Every op takes f32 or f16 slices, all of one dtype (fp16: stored as float16, computed in fp32,
// stored saturated at +-65504); copy alone may convert between an f32 and an f16 slice. The inputs
// are read through texel buffers where they fit (TexelReadOptions; elementwise_texel.comp).
void copy(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt = {});  // out = in (builds concatenations)
void add(CommandStream& cs, Slice a, Slice b, Slice out, const TexelReadOptions& opt = {});  // out = a + b
// out = scale * act(in)
void scale_act(CommandStream& cs, Slice in, Slice out, Act act, float scale, const TexelReadOptions& opt = {});
inline void tanh_scale(CommandStream& cs, Slice in, Slice out, float scale) {
  scale_act(cs, in, out, {Activation::tanh, 0.f}, scale);
}
// out = m * a + (1 - m) * b; m has one channel, broadcast over the channels of a and b.
void blend(CommandStream& cs, Slice m, Slice a, Slice b, Slice out, const TexelReadOptions& opt = {});
void clamp01(CommandStream& cs, Slice in, Slice out, const TexelReadOptions& opt = {});  // out = clamp(in, 0, 1)

void copy_ref(HostSlice in, HostSliceOut out);
void add_ref(HostSlice a, HostSlice b, HostSliceOut out);
void scale_act_ref(HostSlice in, HostSliceOut out, Act act, float scale);
void blend_ref(HostSlice m, HostSlice a, HostSlice b, HostSliceOut out);
void clamp01_ref(HostSlice in, HostSliceOut out);

}  // namespace vkunroll
