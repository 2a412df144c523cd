#version 450
// Reflection padding (PyTorch's ReflectionPad2d where pad < size; reflect_index.glsl for larger pads).
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
#include "reflect_index.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, h, w, oh, ow, top, left; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.oh * p.ow || c >= p.c) return;
  uint oy = i / p.ow, ox = i % p.ow;
  uint iy = reflect_index(int(oy) - int(p.top), int(p.h)), ix = reflect_index(int(ox) - int(p.left), int(p.w));
  y[p.out_off + n * p.out_bs + c * p.oh * p.ow + i] = x[p.in_off + n * p.in_bs + (c * p.h + iy) * p.w + ix];
}
