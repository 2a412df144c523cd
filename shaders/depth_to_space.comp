#version 450
// depth_to_space(2) (PixelShuffle): out[n, c, 2y+i, 2x+j] = in[n, c*4 + i*2 + j, y, x].
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c_out, h, w, oh, ow; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.oh * p.ow || c >= p.c_out) return;
  uint oy = i / p.ow, ox = i % p.ow;
  uint ci = c * 4u + (oy % 2u) * 2u + (ox % 2u);
  y[p.out_off + n * p.out_bs + c * p.oh * p.ow + i] = x[p.in_off + n * p.in_bs + (ci * p.h + oy / 2u) * p.w + ox / 2u];
}
