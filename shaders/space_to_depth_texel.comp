#version 450
// space_to_depth.comp reading its input through a uniform texel buffer (R32, R16 in fp16): on
// llvmpipe a texel fetch is one gather, a storage-buffer load a loop over the lanes. Four outputs
// of a row per invocation (crop_texel.comp); past an odd bottom/right edge the input reads as 0.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(binding = 0) uniform samplerBuffer xin;
layout(std430, binding = 1) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c_out, h, w, oh, ow; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, co = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  uint quads = (p.ow + 3u) / 4u;
  if (i >= p.oh * quads || co >= p.c_out) return;
  uint oy = i / quads, ox = (i % quads) * 4u;
  uint c = co / 4u, dy = (co / 2u) % 2u, dx = co % 2u;
  uint iy = 2u * oy + dy;
  uint row = p.in_off + n * p.in_bs + (c * p.h + min(iy, p.h - 1u)) * p.w;
  uint o = p.out_off + n * p.out_bs + (co * p.oh + oy) * p.ow + ox;
  [[unroll]] for (uint k = 0u; k < 4u; ++k) {
    uint ix = 2u * (ox + k) + dx;
    float v = texelFetch(xin, int(row + min(ix, p.w - 1u))).r;
    if (ox + k < p.ow) y[o + k] = SFLOAT(iy < p.h && ix < p.w ? v : 0.0);
  }
}
