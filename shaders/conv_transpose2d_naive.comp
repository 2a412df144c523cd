#version 450
#extension GL_GOOGLE_include_directive : require
// conv_transpose2d, the baseline: one invocation per output value; input (iy, ix) reaches output
// (iy*S - P + ky, ix*S - P + kx), so each output gathers the taps with matching phase.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(constant_id = 0) const uint K = 4;
layout(constant_id = 1) const uint STRIDE = 2;
layout(constant_id = 2) const uint ACT = 0;
layout(constant_id = 3) const float SLOPE = 0.0;
#include "act.glsl"
#include "precision.glsl"

layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) readonly buffer Wt { SFLOAT wt[]; };  // [cin][cout][K][K]
layout(std430, binding = 2) readonly buffer Bias { float bias[]; };
layout(std430, binding = 3) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad;
} p;

void main() {
  uint ox = gl_GlobalInvocationID.x, oy = gl_GlobalInvocationID.y;
  uint n = gl_GlobalInvocationID.z / p.cout, co = gl_GlobalInvocationID.z % p.cout;
  if (ox >= p.ow || oy >= p.oh) return;
  float acc = bias[co];
  for (uint ky = 0; ky < K; ++ky) {
    int ty = int(oy) + int(p.pad) - int(ky);
    if (ty < 0 || ty % int(STRIDE) != 0) continue;
    uint iy = uint(ty) / STRIDE;
    if (iy >= p.h) continue;
    for (uint kx = 0; kx < K; ++kx) {
      int tx = int(ox) + int(p.pad) - int(kx);
      if (tx < 0 || tx % int(STRIDE) != 0) continue;
      uint ix = uint(tx) / STRIDE;
      if (ix >= p.w) continue;
      for (uint ci = 0; ci < p.cin; ++ci)
        acc += float(x[p.in_off + n * p.in_bs + (ci * p.h + iy) * p.w + ix]) * float(wt[((ci * p.cout + co) * K + ky) * K + kx]);
    }
  }
  y[p.out_off + n * p.out_bs + (co * p.oh + oy) * p.ow + ox] = to_s(act(acc));
}
