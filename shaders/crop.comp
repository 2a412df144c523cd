#version 450
// Crop: out[n, c, y, x] = in[n, c, y + top, x + left].
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, h, w, oh, ow, top, left; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.oh * p.ow || c >= p.c) return;
  uint oy = i / p.ow, ox = i % p.ow;
  y[p.out_off + n * p.out_bs + c * p.oh * p.ow + i] = x[p.in_off + n * p.in_bs + (c * p.h + oy + p.top) * p.w + ox + p.left];
}
