#version 450
// crop.comp reading its input through a uniform texel buffer (R32, R16 in fp16): on llvmpipe a
// texel fetch is one gather, a storage-buffer load a loop over the lanes (reflection_pad_texel.comp).
// Four pixels of a row per invocation, as crop.comp.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(binding = 0) uniform samplerBuffer xin;
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, h, w, oh, ow, top, left; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  uint quads = (p.ow + 3u) / 4u;
  if (i >= p.oh * quads || c >= p.c) return;
  uint oy = i / quads, ox = (i % quads) * 4u;
  uint s = p.in_off + n * p.in_bs + (c * p.h + oy + p.top) * p.w + ox + p.left;
  uint o = p.out_off + n * p.out_bs + (c * p.oh + oy) * p.ow + ox;
  [[unroll]] for (uint k = 0u; k < 4u; ++k)
    if (ox + k < p.ow) y[o + k] = SFLOAT(texelFetch(xin, int(s + k)).r);
}
