#version 450
// space_to_depth(2) (PixelUnshuffle): out[n, c*4 + i*2 + j, y, x] = in[n, c, 2y+i, 2x+j];
// positions past an odd bottom/right edge read as 0 (zero padding to even size).
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c_out, h, w, oh, ow; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, co = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.oh * p.ow || co >= p.c_out) return;
  uint oy = i / p.ow, ox = i % p.ow;
  uint c = co / 4u, dy = (co / 2u) % 2u, dx = co % 2u;
  uint iy = 2u * oy + dy, ix = 2u * ox + dx;
  float v = 0.0;  // f16 -> f32 -> f16 is exact
  if (iy < p.h && ix < p.w) v = float(x[p.in_off + n * p.in_bs + (c * p.h + iy) * p.w + ix]);
  y[p.out_off + n * p.out_bs + co * p.oh * p.ow + i] = SFLOAT(v);
}
