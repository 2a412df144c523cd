// The implicit GEMM's X (im2col, never stored): value (k, gp) read from the input in place, for
// conv2d_igemm and conv2d_igemm_coopmat. The input is up to 5 pieces concatenated along the channels
// (x0..x4, channel starts PC1..PC4), read as they are (MAP 0), reflection-padded to the conv's h x w
// with the pieces at (src_y, src_x) (MAP 1: the UNets' size adapter), or space-to-depth of the pieces
// (MAP 2: channel 4c + 2dy + dx at (y, x) is the piece's channel c at (2y + dy, 2x + dx)), or
// depth-to-space (MAP 3: channel c at (2y + dy, 2x + dx) is the piece's channel 4c + 2dy + dx at (y, x)): the pad,
// concatenation and rearrangement cost no dispatch and no buffer. The includer declares KH, KW,
// STRIDE, MODE, the push constants (igemm_common.glsl) and the buffers x0..x4.
#ifndef VKU_IGEMM_GATHER_GLSL
#define VKU_IGEMM_GATHER_GLSL
layout(constant_id = 17) const uint MAP = 0;
layout(constant_id = 18) const uint PIECES = 1;
layout(constant_id = 19) const uint PC1 = 0xffffffffu;
layout(constant_id = 20) const uint PC2 = 0xffffffffu;
layout(constant_id = 21) const uint PC3 = 0xffffffffu;
layout(constant_id = 22) const uint PC4 = 0xffffffffu;
#define VKU_REFLECT_GENERAL_ONLY
#include "reflect_index.glsl"

// The invocation's fixed column of X: where its output pixel's window starts in the (folded) input.
struct Column {
  bool valid;
  uint item;    // batch item
  int iy, ix;   // input row and column of tap (0, 0)
};

Column column_of(uint gp, uvec2 phase) {
  Column c;
  c.valid = gp < igemm_npix();
  uint g = min(gp, igemm_npix() - 1u), gplane = p.gh * p.gw, r = g % gplane;
  c.item = g / gplane;
  // A conv: pixel (oy, ox) reads from (oy, ox) * STRIDE - pad. A transposed conv's phase (py, px):
  // pixel (qy, qx) reads from (qy, qx) + (phase + pad) / STRIDE - (KH - 1, KW - 1) (conv_transpose2d.cpp
  // packs each phase's taps flipped to match).
  ivec2 base = MODE == 1u ? ivec2((phase + uvec2(p.pad)) / STRIDE) - ivec2(KH - 1u, KW - 1u) : -ivec2(int(p.pad));
  const uint step = MODE == 1u ? 1u : STRIDE;
  c.iy = int((r / p.gw) * step) + base.x;
  c.ix = int((r % p.gw) * step) + base.y;
  return c;
}

// Input value (channel ci, row iy, column ix) of batch item `item` as the conv sees it, (iy, ix) inside.
float folded_input(uint item, uint ci, uint iy, uint ix) {
  uint piece = 0u, c0 = 0u;
  if (PIECES > 1u && ci >= PC1) piece = 1u, c0 = PC1;
  if (PIECES > 2u && ci >= PC2) piece = 2u, c0 = PC2;
  if (PIECES > 3u && ci >= PC3) piece = 3u, c0 = PC3;
  if (PIECES > 4u && ci >= PC4) piece = 4u, c0 = PC4;
  uint sc = ci - c0, sy = iy, sx = ix;
  if (MAP == 1u) {
    sy = reflect_index(int(iy) - int(p.src_y), int(p.src_h));
    sx = reflect_index(int(ix) - int(p.src_x), int(p.src_w));
  } else if (MAP == 2u) {
    sy = 2u * iy + (sc % 4u) / 2u, sx = 2u * ix + sc % 2u, sc /= 4u;
  } else if (MAP == 3u) {
    sc = 4u * sc + 2u * (iy % 2u) + ix % 2u, sy = iy / 2u, sx = ix / 2u;
  }
  uint at = sc * p.src_h * p.src_w + sy * p.src_w + sx;
  if (piece == 0u) return float(x0[p.in_off + item * p.in_bs + at]);
  uint base = p.piece_off[piece - 1u] + item * p.piece_bs[piece - 1u] + at;
  if (piece == 1u) return float(x1[base]);
  if (piece == 2u) return float(x2[base]);
  if (piece == 3u) return float(x3[base]);
  return float(x4[base]);
}

float gather(Column c, uint k) {
  uint ci = k / (KH * KW), t = k - ci * (KH * KW), ky = t / KW, kx = t - ky * KW;
  int iy = c.iy + int(ky), ix = c.ix + int(kx);
  bool ok = c.valid && k < p.kdim && iy >= 0 && iy < int(p.h) && ix >= 0 && ix < int(p.w);
  float v = 0.0;
  if (ok) v = folded_input(c.item, ci, uint(iy), uint(ix));
  return v;
}

#endif
