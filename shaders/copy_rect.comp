#version 450
// Rectangle copy: out[n, c, dy + i, dx + j] = in[n, c, sy + i, sx + j] for i < rh, j < rw.
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, ih, iw, oh, ow, sy, sx, dy, dx, rh, rw; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.rh * p.rw || c >= p.c) return;
  uint ry = i / p.rw, rx = i % p.rw;
  y[p.out_off + n * p.out_bs + (c * p.oh + p.dy + ry) * p.ow + p.dx + rx] =
      x[p.in_off + n * p.in_bs + (c * p.ih + p.sy + ry) * p.iw + p.sx + rx];
}
