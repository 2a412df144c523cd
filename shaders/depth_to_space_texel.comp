#version 450
// depth_to_space.comp reading its input through a uniform texel buffer (R32, R16 in fp16): on
// llvmpipe a texel fetch is one gather, a storage-buffer load a loop over the lanes. Four outputs
// of a row per invocation (crop_texel.comp); the output width is even, so the row starts at an
// even column and output ox + k reads input column ox / 2 + k / 2 of channel c*4 + (oy%2)*2 + k%2.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(binding = 0) uniform samplerBuffer xin;
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c_out, h, w, oh, ow; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  uint quads = (p.ow + 3u) / 4u;
  if (i >= p.oh * quads || c >= p.c_out) return;
  uint oy = i / quads, ox = (i % quads) * 4u;
  uint plane = p.h * p.w;
  uint s = p.in_off + n * p.in_bs + (c * 4u + (oy % 2u) * 2u) * plane + (oy / 2u) * p.w + ox / 2u;
  uint o = p.out_off + n * p.out_bs + (c * p.oh + oy) * p.ow + ox;
  [[unroll]] for (uint k = 0u; k < 4u; ++k)
    if (ox + k < p.ow) y[o + k] = SFLOAT(texelFetch(xin, int(s + (k % 2u) * plane + k / 2u)).r);
}
