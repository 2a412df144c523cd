// The body of winograd_input.comp (input in a storage buffer) and winograd_input_texel.comp (through
// a uniform texel buffer, WINOGRAD_TEXEL_INPUT; the .comp includes precision.glsl first).
// Winograd F(4x4, 3x3), step 1: the input transform V = B^T d B of the 6x6 input tiles (stride 4),
// four horizontally adjacent tiles per invocation: their 6x18 input window is loaded once and each
// of the 36 transformed positions is stored as one vec4 (4 tiles).
// A 5x5 conv is four 3x3 convs on shifted inputs (kernel split into 3x3 blocks at offsets 0 and 3):
// virtual channel cc = s * cin + ci reads channel ci shifted by (3 (s / KS), 3 (s % KS)), KS = 1 or 2.
// A 3x3 stride-2 conv is four 3x3 stride-1 convs on the 2x2 phase images x(2u + a, 2v + b)
// (s_in = 2): virtual channel s = a * 2 + b. In general the tile row i of virtual channel s reads
// input row s_in * (4 ty - 1 + i) + off_mul * (s / ks) + off_base (columns likewise with s % ks).
// Channels [c_begin, c_begin + gridY) of the virtual ones are transformed (a chunk).
// Layout [36][rows][tiles_pad] (rows v0 + channel), tile index ((n * tiles_y + ty) * tiles_x_pad + tx);
// with ilv = TV, the texel GEMM's [36][tiles_pad / (4 TV)][rows][TV] vec4s: each lane of the GEMM
// then reads one run of memory over its channel loop.
// fp16 variant: the input as float16; V stays fp32 (F(4,3)'s transforms amplify V's rounding: fp16 V
// measured 6-8e-3 max abs error against 2.5e-4 for fp16 weights alone, docs/kernels.md "Precision").
#include "winograd_input_io.glsl"

// The 4 tiles of group gi (of 4 horizontally adjacent tiles) in channel cl of the chunk.
void transform(uint gi, uint cl) {
  uint cc = p.c_begin + cl, sh = cc / p.cin, ci = cc % p.cin;
  uint gx = p.tiles_x_pad / 4u;
  uint row = gi / gx, n = row / p.tiles_y, ty = row % p.tiles_y;
  int si = int(p.s_in);
  int y0 = si * (int(ty) * 4 - 1) + int(p.off_mul * (sh / p.ks)) + p.off_base;
  int x0 = si * (int(gi % gx) * 16 - 1) + int(p.off_mul * (sh % p.ks)) + p.off_base;
  uint base = p.in_off + n * p.in_bs + ci * p.h * p.w;
  float d[6][18];
  [[unroll]] for (int i = 0; i < 6; ++i) {
    int yy = y0 + si * i;
    bool rowok = yy >= 0 && yy < int(p.h);
    uint rb = base + uint(clamp(yy, 0, int(p.h) - 1)) * p.w;
    [[unroll]] for (int j = 0; j < 18; ++j) {
      int xx = x0 + si * j;
      float val = load_input(rb + uint(clamp(xx, 0, int(p.w) - 1)));
      d[i][j] = (rowok && xx >= 0 && xx < int(p.w)) ? val : 0.0;
    }
  }
  vec4 t6[6][6];  // B^T d, the 4 tiles side by side in the vec4 components
  [[unroll]] for (int j = 0; j < 6; ++j) {
    vec4 d0 = vec4(d[0][j], d[0][j + 4], d[0][j + 8], d[0][j + 12]);
    vec4 d1 = vec4(d[1][j], d[1][j + 4], d[1][j + 8], d[1][j + 12]);
    vec4 d2 = vec4(d[2][j], d[2][j + 4], d[2][j + 8], d[2][j + 12]);
    vec4 d3 = vec4(d[3][j], d[3][j + 4], d[3][j + 8], d[3][j + 12]);
    vec4 d4 = vec4(d[4][j], d[4][j + 4], d[4][j + 8], d[4][j + 12]);
    vec4 d5 = vec4(d[5][j], d[5][j + 4], d[5][j + 8], d[5][j + 12]);
    t6[0][j] = 4.0 * d0 - 5.0 * d2 + d4;
    t6[1][j] = -4.0 * d1 - 4.0 * d2 + d3 + d4;
    t6[2][j] = 4.0 * d1 - 4.0 * d2 - d3 + d4;
    t6[3][j] = -2.0 * d1 - d2 + 2.0 * d3 + d4;
    t6[4][j] = 2.0 * d1 - d2 - 2.0 * d3 + d4;
    t6[5][j] = 4.0 * d1 - 5.0 * d3 + d5;
  }
  uint stride = p.rows * p.tiles_pad / 4u, vr = p.v0 + cl;
  uint o = p.ilv == 0u ? vr * p.tiles_pad / 4u + gi : ((gi / p.ilv) * p.rows + vr) * p.ilv + gi % p.ilv;
  [[unroll]] for (int i = 0; i < 6; ++i) {  // (B^T d) B
    vec4 r0 = t6[i][0], r1 = t6[i][1], r2 = t6[i][2], r3 = t6[i][3], r4 = t6[i][4], r5 = t6[i][5];
    uint b = uint(i * 6) * stride + o;
    v[b] = 4.0 * r0 - 5.0 * r2 + r4;
    v[b + stride] = -4.0 * r1 - 4.0 * r2 + r3 + r4;
    v[b + 2u * stride] = 4.0 * r1 - 4.0 * r2 - r3 + r4;
    v[b + 3u * stride] = -2.0 * r1 - r2 + 2.0 * r3 + r4;
    v[b + 4u * stride] = 2.0 * r1 - r2 - 2.0 * r3 + r4;
    v[b + 5u * stride] = 4.0 * r1 - 5.0 * r3 + r5;
  }
}
