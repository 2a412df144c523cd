// The body of winograd_gemm.comp (V and U in storage buffers) and winograd_gemm_texel.comp (through
// uniform texel buffers, WINOGRAD_GEMM_TEXEL). Winograd F(4x4, 3x3), step 2: for each of the NPOS
// tile positions, M (+)= U V over a chunk of input channels: a register-blocked GEMM, 4 TV tiles x
// COB output channels per invocation, vec4 loads of both operands (U [36][cin_total][cout_pad],
// M [36][cout_pad][tiles_pad]). ACCUM adds to M (the chunks after the first).
// V: [36][rows][tiles_pad] in storage buffers; [36][tiles_pad / (4 TV)][rows][TV] vec4s through
// texels, as winograd_input writes it with ilv = TV, so each lane's loop over its channels walks one
// contiguous run (that GEMM 1.4x faster than on the other order). rows >= chunk: a dense block's
// shared V holds more channels than one conv reads.
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint COB = 8;
layout(constant_id = 1) const uint ACCUM = 0;
layout(constant_id = 2) const uint NPOS = 36;  // tile positions (36; 1 for a 1x1 conv as a plain GEMM)
layout(constant_id = 3) const uint TV = 2;     // vec4s of tiles per invocation (tiles_pad is a multiple of 16)
#ifdef WINOGRAD_GEMM_TEXEL
layout(binding = 0) uniform samplerBuffer v;
layout(binding = 1) uniform samplerBuffer u;
vec4 load_v(int i) { return texelFetch(v, i); }
vec4 load_u(int i) { return texelFetch(u, i); }
#else
layout(std430, binding = 0) readonly buffer V { SVEC4 v[]; };
layout(std430, binding = 1) readonly buffer U { SVEC4 u[]; };
vec4 load_v(int i) { return vec4(v[i]); }
vec4 load_u(int i) { return vec4(u[i]); }
#endif
layout(std430, binding = 2) buffer M { vec4 m[]; };
layout(push_constant) uniform P { uint chunk, tiles_pad, cout_pad, cin_total, c_begin, rows; } p;

void main() {
  // Invocations numbered over (position, channel block, group of 4 TV tiles): small images with
  // few tiles still fill every workgroup.
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
#ifdef WINOGRAD_GEMM_TEXEL
  const uint vtile = p.rows * TV, vstep = TV;  // this tile group's run, one channel's TV vec4s
#else
  const uint vtile = TV, vstep = vs;           // this tile group's vec4s in each channel row
#endif
  int vb = int(pos * p.rows * vs + tg * vtile), ub = int((pos * p.cin_total + p.c_begin) * us + cog * (COB / 4u));
  for (uint ci = 0; ci < p.chunk; ++ci, vb += int(vstep), ub += int(us)) {
    vec4 vv[TV];
    [[unroll]] for (uint t = 0; t < TV; ++t) vv[t] = load_v(vb + int(t));
    [[unroll]] for (uint q = 0; q < COB / 4u; ++q) {
      vec4 w = load_u(ub + int(q));
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
