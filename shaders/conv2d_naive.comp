#version 450
#extension GL_GOOGLE_include_directive : require
// conv2d, the baseline: one invocation per output value, direct loops over cin and the kernel.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(constant_id = 0) const uint K = 3;
layout(constant_id = 1) const uint STRIDE = 1;
layout(constant_id = 2) const uint ACT = 0;
layout(constant_id = 3) const float SLOPE = 0.0;
layout(constant_id = 4) const uint HAS_RES = 0;
#include "act.glsl"
#include "precision.glsl"

layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) readonly buffer Wt { SFLOAT wt[]; };   // [cout][cin][K][K]
layout(std430, binding = 2) readonly buffer Bias { float bias[]; };
layout(std430, binding = 3) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = 4) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad;
} p;

void main() {
  uint ox = gl_GlobalInvocationID.x, oy = gl_GlobalInvocationID.y;
  uint n = gl_GlobalInvocationID.z / p.cout, co = gl_GlobalInvocationID.z % p.cout;
  if (ox >= p.ow || oy >= p.oh) return;
  int iy0 = int(oy * STRIDE) - int(p.pad), ix0 = int(ox * STRIDE) - int(p.pad);
  float acc = bias[co];
  for (uint ci = 0; ci < p.cin; ++ci) {
    uint ib = p.in_off + n * p.in_bs + ci * p.h * p.w;
    uint wb = (co * p.cin + ci) * K * K;
    for (uint ky = 0; ky < K; ++ky) {
      int iy = iy0 + int(ky);
      if (iy < 0 || iy >= int(p.h)) continue;
      for (uint kx = 0; kx < K; ++kx) {
        int ix = ix0 + int(kx);
        if (ix < 0 || ix >= int(p.w)) continue;
        acc += float(x[ib + uint(iy) * p.w + uint(ix)]) * float(wt[wb + ky * K + kx]);
      }
    }
  }
  float v = act(acc);
  uint o = (co * p.oh + oy) * p.ow + ox;
  if (HAS_RES != 0u) v += float(res[p.res_off + n * p.res_bs + o]);
  y[p.out_off + n * p.out_bs + o] = to_s(v);
}
