#version 450
// 1x1 conv as a GEMM, step 1, for winograd_gemm_texel: a chunk of input channels, read through a
// uniform texel buffer (R32, R16 in fp16), into that GEMM's order [pix_pad / (4 TV)][chunk][TV]
// vec4s (pixels of all batch items in a row, t = n * plane + p; pixels past the end are 0). Lanes
// over channels, each invocation writing the TV adjacent vec4s of one GEMM pixel group: every
// cache line of V then has one writer (winograd_input's ilv order, docs/kernels.md).
// fp16 variant: input and V as float16 (a copy: no scaling).
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint TV = 4;
layout(binding = 0) uniform samplerBuffer xin;
layout(std430, binding = 1) writeonly buffer V { SVEC4 v[]; };
layout(push_constant) uniform P { uint in_off, in_bs, plane, npix, pix_pad, c_begin, chunk; } p;
void main() {
  uint idx = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  uint cl = idx % p.chunk, grp = idx / p.chunk;
  if (grp * 4u * TV >= p.pix_pad) return;
  uint ci = p.c_begin + cl;
  [[unroll]] for (uint t = 0; t < TV; ++t) {
    vec4 r;
    [[unroll]] for (uint k = 0; k < 4u; ++k) {
      uint px = (grp * TV + t) * 4u + k, q = min(px, p.npix - 1u);
      float val = texelFetch(xin, int(p.in_off + (q / p.plane) * p.in_bs + ci * p.plane + q % p.plane)).r;
      r[k] = px < p.npix ? val : 0.0;
    }
    v[(grp * p.chunk + cl) * TV + t] = SVEC4(r);
  }
}
