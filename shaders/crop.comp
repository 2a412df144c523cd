#version 450
// Crop: out[n, c, y, x] = in[n, c, y + top, x + left]. Four pixels of a row per invocation: on
// llvmpipe an invocation's fixed cost (index math, bounds) is most of a one-value copy's time.
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, h, w, oh, ow, top, left; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  uint quads = (p.ow + 3u) / 4u;
  if (i >= p.oh * quads || c >= p.c) return;
  uint oy = i / quads, ox = (i % quads) * 4u;
  uint o = p.out_off + n * p.out_bs + (c * p.oh + oy) * p.ow + ox;
  uint s = p.in_off + n * p.in_bs + (c * p.h + oy + p.top) * p.w + ox + p.left;
  uint count = min(4u, p.ow - ox);
  for (uint k = 0u; k < count; ++k) y[o + k] = x[s + k];
}
