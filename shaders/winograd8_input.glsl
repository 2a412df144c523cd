// The body of winograd45_input.comp / winograd63_input.comp (input in a storage buffer) and their
// _texel forms (through a uniform texel buffer, WINOGRAD_TEXEL_INPUT; the .comp includes
// precision.glsl first). Winograd on 8x8 input tiles with the points 0, +-1, +-2, +-1/2, inf (one B^T
// for both forms): F(4x4, 5x5) (TILE_OUT 4: tiles at stride 4) or F(6x6, 3x3) (TILE_OUT 6: stride 6).
// Step 1, V = B^T d B, four horizontally adjacent tiles per invocation: their 8 x (3 TILE_OUT + 8)
// input window is loaded once and each of the 64 transformed positions is stored as one vec4 (4
// tiles). Layouts, push constants and chunks as winograd_input.glsl (stride 1, no virtual channels:
// ks = 1); the window starts at (TILE_OUT ty + off_base, 4 TILE_OUT gx + off_base), off_base = -pad.
#ifndef TILE_OUT
#define TILE_OUT 4
#endif
const int TO = TILE_OUT, WIN = 3 * TILE_OUT + 8;
// fp16 variant: the input as float16; V stays fp32.
#include "winograd_input_io.glsl"

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
  int y0 = int(ty) * TO + p.off_base, x0 = int(gi % gx) * 4 * TO + p.off_base;
  uint base = p.in_off + n * p.in_bs + ci * p.h * p.w;
  float d[8][WIN];
  [[unroll]] for (int i = 0; i < 8; ++i) {
    int yy = y0 + i;
    bool rowok = yy >= 0 && yy < int(p.h);
    uint rb = base + uint(clamp(yy, 0, int(p.h) - 1)) * p.w;
    [[unroll]] for (int j = 0; j < WIN; ++j) {
      int xx = x0 + j;
      float val = load_input(rb + uint(clamp(xx, 0, int(p.w) - 1)));
      d[i][j] = (rowok && xx >= 0 && xx < int(p.w)) ? val : 0.0;
    }
  }
  vec4 t8[8][8];  // B^T d, the 4 tiles side by side in the vec4 components
  [[unroll]] for (int j = 0; j < 8; ++j) {
    vec4 r[8];
    vec4 c[8];  // column j of each of the 4 tiles
    [[unroll]] for (int i = 0; i < 8; ++i) c[i] = vec4(d[i][j], d[i][j + TO], d[i][j + 2 * TO], d[i][j + 3 * TO]);
    bt8(c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], r);
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
