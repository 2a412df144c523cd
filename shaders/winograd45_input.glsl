// The body of winograd45_input.comp (input in a storage buffer) and winograd45_input_texel.comp
// (through a uniform texel buffer, WINOGRAD_TEXEL_INPUT; the .comp includes precision.glsl first).
// Winograd F(4x4, 5x5), step 1: V = B^T d B of the 8x8 input tiles (stride 4) on the points 0, +-1,
// +-2, +-1/2, inf, four horizontally adjacent tiles per invocation: their 8x20 input window is
// loaded once and each of the 64 transformed positions is stored as one vec4 (4 tiles). Layouts,
// push constants and chunks as winograd_input.glsl (stride 1, no virtual channels: ks = 1); the
// window starts at (4 ty + off_base, 16 gx + off_base), off_base = -pad.
// fp16 variant: the input as float16; V stays fp32.
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
  uint ilv, rows, v0;
} p;

// B^T x for one column (or row) of 8 values, 4 tiles side by side.
void bt8(vec4 d0, vec4 d1, vec4 d2, vec4 d3, vec4 d4, vec4 d5, vec4 d6, vec4 d7, out vec4 r[8]) {
  r[0] = d0 - 5.25 * d2 + 5.25 * d4 - d6;
  r[1] = d1 + d2 - 4.25 * d3 - 4.25 * d4 + d5 + d6;
  r[2] = -d1 + d2 + 4.25 * d3 - 4.25 * d4 - d5 + d6;
  r[3] = 0.5 * d1 + 0.25 * d2 - 2.5 * d3 - 1.25 * d4 + 2.0 * d5 + d6;
  r[4] = -0.5 * d1 + 0.25 * d2 + 2.5 * d3 - 1.25 * d4 - 2.0 * d5 + d6;
  r[5] = 2.0 * d1 + 4.0 * d2 - 2.5 * d3 - 5.0 * d4 + 0.5 * d5 + d6;
  r[6] = -2.0 * d1 + 4.0 * d2 + 2.5 * d3 - 5.0 * d4 - 0.5 * d5 + d6;
  r[7] = -d1 + 5.25 * d3 - 5.25 * d5 + d7;
}

// The 4 tiles of group gi (of 4 horizontally adjacent tiles) in channel cl of the chunk.
void transform(uint gi, uint cl) {
  uint ci = p.c_begin + cl;
  uint gx = p.tiles_x_pad / 4u;
  uint row = gi / gx, n = row / p.tiles_y, ty = row % p.tiles_y;
  int y0 = int(ty) * 4 + p.off_base, x0 = int(gi % gx) * 16 + p.off_base;
  uint base = p.in_off + n * p.in_bs + ci * p.h * p.w;
  float d[8][20];
  [[unroll]] for (int i = 0; i < 8; ++i) {
    int yy = y0 + i;
    bool rowok = yy >= 0 && yy < int(p.h);
    uint rb = base + uint(clamp(yy, 0, int(p.h) - 1)) * p.w;
    [[unroll]] for (int j = 0; j < 20; ++j) {
      int xx = x0 + j;
      float val = load_input(rb + uint(clamp(xx, 0, int(p.w) - 1)));
      d[i][j] = (rowok && xx >= 0 && xx < int(p.w)) ? val : 0.0;
    }
  }
  vec4 t8[8][8];  // B^T d, the 4 tiles side by side in the vec4 components
  [[unroll]] for (int j = 0; j < 8; ++j) {
    vec4 r[8];
    bt8(vec4(d[0][j], d[0][j + 4], d[0][j + 8], d[0][j + 12]), vec4(d[1][j], d[1][j + 4], d[1][j + 8], d[1][j + 12]),
        vec4(d[2][j], d[2][j + 4], d[2][j + 8], d[2][j + 12]), vec4(d[3][j], d[3][j + 4], d[3][j + 8], d[3][j + 12]),
        vec4(d[4][j], d[4][j + 4], d[4][j + 8], d[4][j + 12]), vec4(d[5][j], d[5][j + 4], d[5][j + 8], d[5][j + 12]),
        vec4(d[6][j], d[6][j + 4], d[6][j + 8], d[6][j + 12]), vec4(d[7][j], d[7][j + 4], d[7][j + 8], d[7][j + 12]), r);
    [[unroll]] for (int i = 0; i < 8; ++i) t8[i][j] = r[i];
  }
  uint stride = p.rows * p.tiles_pad / 4u, vr = p.v0 + cl;
  uint o = p.ilv == 0u ? vr * p.tiles_pad / 4u + gi : ((gi / p.ilv) * p.rows + vr) * p.ilv + gi % p.ilv;
  [[unroll]] for (int i = 0; i < 8; ++i) {  // (B^T d) B
    vec4 r[8];
    bt8(t8[i][0], t8[i][1], t8[i][2], t8[i][3], t8[i][4], t8[i][5], t8[i][6], t8[i][7], r);
    uint b = uint(i * 8) * stride + o;
    [[unroll]] for (int j = 0; j < 8; ++j) v[b + uint(j) * stride] = r[j];
  }
}

void main() {
  if (p.ilv == 0u) {  // lanes over tile groups, one per invocation
    if (gl_GlobalInvocationID.x < p.ngroups) transform(gl_GlobalInvocationID.x, gl_GlobalInvocationID.y);
    return;
  }
  // ilv = TV: lanes over channels, each writing the TV adjacent vec4s of one GEMM tile group.
  uint idx = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  uint cl = idx % p.chunk, g0 = (idx / p.chunk) * p.ilv;
  for (uint t = 0u; t < p.ilv; ++t)
    if (g0 + t < p.ngroups) transform(g0 + t, cl);
}
