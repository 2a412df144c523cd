// What every Winograd output transform shares (winograd_output.glsl, winograd8_output.glsl): the
// activation, M (a uniform texel view with WINOGRAD_TEXEL_M, else a storage buffer), bias, residual,
// output and push constants, and the store of one output value.
// fp16 variant: M stays fp32, residual and output float16.
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint ACT = 0;
layout(constant_id = 1) const float SLOPE = 0.0;
layout(constant_id = 2) const uint HAS_RES = 0;
#include "act.glsl"
#ifdef WINOGRAD_TEXEL_M
layout(binding = 0) uniform samplerBuffer mt;
vec4 load_m(uint i) { return texelFetch(mt, int(i)); }
#else
layout(std430, binding = 0) readonly buffer M { vec4 m[]; };
vec4 load_m(uint i) { return m[i]; }
#endif
layout(std430, binding = 1) readonly buffer Bias { float bias[]; };
layout(std430, binding = 2) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = 3) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint res_off, res_bs, out_off, out_bs, cout, oh, ow, tiles_x_pad, tiles_y, ngroups, tiles_pad, cout_pad;
} p;

// Output (oy, ox) of the plane at `ob` (its residual's at `rb`): activation of `sum` (bias added),
// then the residual; nothing past the image's bottom or right edge.
void store_output(uint ob, uint rb, uint oy, uint ox, float sum) {
  if (oy >= p.oh || ox >= p.ow) return;
  uint o = oy * p.ow + ox;
  float val = act(sum);
  if (HAS_RES != 0u) val += float(res[rb + o]);
  y[ob + o] = to_s(val);
}
