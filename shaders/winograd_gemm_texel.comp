#version 450
// Winograd F(4x4, 3x3), step 2, with V and U read through RGBA32F uniform texel buffers: the same
// register-blocked GEMM as winograd_gemm.comp, V's rows interleaved (below) (fp32 only: Winograd keeps U and V fp32 in both
// precisions), but llvmpipe fetches a texel with one gather where a storage-buffer load is a
// per-lane loop (docs/kernels.md); the host takes it where V and U fit maxTexelBufferElements.
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint COB = 8;
layout(constant_id = 1) const uint ACCUM = 0;
layout(constant_id = 2) const uint NPOS = 36;
layout(constant_id = 3) const uint TV = 2;
layout(binding = 0) uniform samplerBuffer v;
layout(binding = 1) uniform samplerBuffer u;
layout(std430, binding = 2) buffer M { vec4 m[]; };
// rows: V's rows (>= chunk; a dense block's shared V holds more channels than this conv reads).
layout(push_constant) uniform P { uint chunk, tiles_pad, cout_pad, cin_total, c_begin, rows; } p;

void main() {
  uint groups = p.tiles_pad / (4u * TV), cogs = p.cout_pad / COB;
  uint idx = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  bool live = idx < NPOS * cogs * groups;
  idx = min(idx, NPOS * cogs * groups - 1u);
  uint tg = idx % groups, cog = (idx / groups) % cogs, pos = idx / (groups * cogs);
  uint vs = p.tiles_pad / 4u, us = p.cout_pad / 4u;
  vec4 acc[COB][TV];
  [[unroll]] for (uint c = 0; c < COB; ++c) {
    uint mb = (pos * p.cout_pad + cog * COB + c) * vs + tg * TV;
    [[unroll]] for (uint t = 0; t < TV; ++t) acc[c][t] = ACCUM != 0u ? m[mb + t] : vec4(0.0);
  }
  // V as winograd_input writes it with ilv = TV: [36][groups][rows][TV] vec4s, so this lane's loop
  // over channels walks one contiguous run (the GEMM 1.4x faster than on [36][chunk][tiles]).
  int vb = int(pos * p.rows * vs + tg * p.rows * TV), ub = int((pos * p.cin_total + p.c_begin) * us + cog * (COB / 4u));
  for (uint ci = 0; ci < p.chunk; ++ci, vb += int(TV), ub += int(us)) {
    vec4 vv[TV];
    [[unroll]] for (uint t = 0; t < TV; ++t) vv[t] = texelFetch(v, vb + int(t));
    [[unroll]] for (uint q = 0; q < COB / 4u; ++q) {
      vec4 w = texelFetch(u, ub + int(q));
      [[unroll]] for (uint c = 0; c < 4u; ++c)
        [[unroll]] for (uint t = 0; t < TV; ++t) acc[q * 4u + c][t] += w[c] * vv[t];
    }
  }
  if (!live) return;
  [[unroll]] for (uint c = 0; c < COB; ++c) {
    uint mb = (pos * p.cout_pad + cog * COB + c) * vs + tg * TV;
    [[unroll]] for (uint t = 0; t < TV; ++t) m[mb + t] = acc[c][t];
  }
}
