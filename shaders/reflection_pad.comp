#version 450
// Reflection padding (PyTorch's ReflectionPad2d where pad < size); larger pads keep reflecting
// (period 2(n-1)), and a size-1 axis repeats its one value.
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, h, w, oh, ow, top, left; } p;
// The folding is even (index -i maps like i), so the remainder is taken of |i|: Vulkan leaves
// OpSMod/OpSRem of a negative operand undefined (NVIDIA returned wrong indices; lavapipe did not).
uint reflect_index(int i, int n) {
  if (n == 1) return 0u;
  uint period = 2u * uint(n - 1);
  uint r = uint(abs(i)) % period;
  return r >= uint(n) ? period - r : r;
}
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.oh * p.ow || c >= p.c) return;
  uint oy = i / p.ow, ox = i % p.ow;
  uint iy = reflect_index(int(oy) - int(p.top), int(p.h)), ix = reflect_index(int(ox) - int(p.left), int(p.w));
  y[p.out_off + n * p.out_bs + c * p.oh * p.ow + i] = x[p.in_off + n * p.in_bs + (c * p.h + iy) * p.w + ix];
}
