// What every Winograd input transform shares (winograd_input.glsl, winograd8_input.glsl): the input
// binding (a uniform texel view with WINOGRAD_TEXEL_INPUT, else a storage buffer), V, the push
// constants, and main(), which hands each invocation its tile groups and channel; the body defines
// transform(gi, cl), the 4 tiles of group gi in channel cl of the chunk.
layout(local_size_x = 64) in;
#ifdef WINOGRAD_TEXEL_INPUT
layout(binding = 0) uniform samplerBuffer xin;  // an R32 view (R16 in fp16): one gather on llvmpipe
float load_input(uint i) { return texelFetch(xin, int(i)).r; }
#else
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
float load_input(uint i) { return float(x[i]); }
#endif
layout(std430, binding = 1) writeonly buffer V { vec4 v[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, cin, h, w, tiles_x_pad, tiles_y, ngroups, tiles_pad, ks, c_begin, chunk, s_in, off_mul;
  int off_base;
  uint ilv;  // 0: [positions][rows][tiles_pad / 4] vec4s; TV: winograd_gemm_texel's [positions][groups][rows][TV]
  uint rows, v0;  // V's rows and the first one written (a dense block's shared V: its new channels)
} p;

void transform(uint gi, uint cl);

void main() {
  // transform() is called in one place: llvmpipe runs both sides of a branch under a mask, and a
  // call in each branch of the two layouts below cost about 10% of this pass there (measured).
  uint g0, cl, count;
  if (p.ilv == 0u) {  // lanes over tile groups, one per invocation
    g0 = gl_GlobalInvocationID.x;
    cl = gl_GlobalInvocationID.y;
    count = 1u;
  } else {
    // ilv = TV: lanes over channels, each writing the TV adjacent vec4s of one GEMM tile group, so
    // every cache line of V has one writer (0.5x the time of one group per invocation there).
    uint idx = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
    cl = idx % p.chunk;
    g0 = (idx / p.chunk) * p.ilv;
    count = p.ilv;
  }
  for (uint t = 0u; t < count; ++t)
    if (g0 + t < p.ngroups) transform(g0 + t, cl);
}
