#version 450
// Rectangle fill: out[n, c, y0 + i, x0 + j] = value for i < rh, j < rw.
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint out_off, out_bs, c, oh, ow, y0, x0, rh, rw; float value; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.rh * p.rw || c >= p.c) return;
  y[p.out_off + n * p.out_bs + (c * p.oh + p.y0 + i / p.rw) * p.ow + p.x0 + i % p.rw] = to_s(p.value);
}
