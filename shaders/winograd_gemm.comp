#version 450
// Winograd F(4x4, 3x3), step 2: for each of the 36 tile positions, M (+)= U V over a chunk of input
// channels: a register-blocked GEMM, 8 tiles x COB output channels per invocation, vec4 loads of
// both operands (U [36][cin_total][cout_pad], V [36][chunk][tiles_pad], M [36][cout_pad][tiles_pad]).
// ACCUM adds to M (the chunks after the first).
// fp16 variant (the 1x1 GEMM's: Winograd keeps U and V fp32 and runs the fp32 one): U and V as
// float16, M (the accumulators) fp32.
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint COB = 8;
layout(constant_id = 1) const uint ACCUM = 0;
layout(constant_id = 2) const uint NPOS = 36;  // tile positions (36; 1 for a 1x1 conv as a plain GEMM)
layout(constant_id = 3) const uint TV = 2;     // vec4s of tiles per invocation (tiles_pad is a multiple of 16)
layout(std430, binding = 0) readonly buffer V { SVEC4 v[]; };
layout(std430, binding = 1) readonly buffer U { SVEC4 u[]; };
layout(std430, binding = 2) buffer M { vec4 m[]; };
layout(push_constant) uniform P { uint chunk, tiles_pad, cout_pad, cin_total, c_begin; } p;

void main() {
  // Invocations numbered over (position, channel block, group of 8 tiles): small images with
  // few tiles still fill every workgroup.
  uint groups = p.tiles_pad / (4u * TV), cogs = p.cout_pad / COB;
  uint idx = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  bool live = idx < NPOS * cogs * groups;
  idx = min(idx, NPOS * cogs * groups - 1u);
  uint tg = idx % groups, cog = (idx / groups) % cogs, pos = idx / (groups * cogs);
  uint vs = p.tiles_pad / 4u, us = p.cout_pad / 4u;
  vec4 acc[COB][TV];
  for (uint c = 0; c < COB; ++c) {
    uint mb = (pos * p.cout_pad + cog * COB + c) * vs + tg * TV;
    for (uint t = 0; t < TV; ++t) acc[c][t] = ACCUM != 0u ? m[mb + t] : vec4(0.0);
  }
  uint vb = pos * p.chunk * vs + tg * TV, ub = (pos * p.cin_total + p.c_begin) * us + cog * (COB / 4u);
  for (uint ci = 0; ci < p.chunk; ++ci, vb += vs, ub += us) {
    vec4 vv[TV];
    for (uint t = 0; t < TV; ++t) vv[t] = vec4(v[vb + t]);
    for (uint q = 0; q < COB / 4u; ++q) {
      vec4 w = vec4(u[ub + q]);
      for (uint c = 0; c < 4u; ++c)
        for (uint t = 0; t < TV; ++t) acc[q * 4u + c][t] += w[c] * vv[t];
    }
  }
  if (!live) return;
  for (uint c = 0; c < COB; ++c) {
    uint mb = (pos * p.cout_pad + cog * COB + c) * vs + tg * TV;
    for (uint t = 0; t < TV; ++t) m[mb + t] = acc[c][t];
  }
}
