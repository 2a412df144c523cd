// The implicit GEMM's X (im2col, never stored): value (k, gp) read from the input in place, for
// conv2d_igemm and conv2d_igemm_coopmat. K is tap-major: k = tap * cin_pad + ci (tap = ky * KW + kx,
// cin_pad = kpad / (KH KW), a whole number of stages), so a stage reads one tap of BK consecutive
// channels: tap_read works out the column's bounds and address once a stage, and gather_at is an
// address, a compare and a load per element. The input is up to 5 pieces concatenated along the
// channels (x0..x4, channel starts PC1..PC4), read as they are (MAP 0), reflection-padded to the
// conv's h x w with the pieces at (src_y, src_x) (MAP 1: the UNets' size adapter), or space-to-depth
// of the pieces (MAP 2: channel 4c + 2dy + dx at (y, x) is the piece's channel c at (2y + dy, 2x + dx)),
// or depth-to-space (MAP 3: channel c at (2y + dy, 2x + dx) is the piece's channel 4c + 2dy + dx at
// (y, x)): the pad, concatenation and rearrangement cost no dispatch and no buffer. The includer
// declares KH, KW, STRIDE, MODE, the push constants (igemm_common.glsl) and the buffers x0..x4.
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

const bool IG_PLAIN = MAP == 0u && PIECES == 1u;  // one piece read as it is: the model's most convs

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

// A column at one tap: the channels it reads there (the input's, or none outside the input: zeros)
// and where channel 0 lies (plain: its element in x0; folded: its pixel in the pieces' planes).
struct TapRead {
  uint lim;   // channels ci < lim are read; p.cin inside the input, 0 outside
  uint base;
  uint item;  // batch item (folded)
  uint sub;   // MAP 3: the sub-pixel 2 (iy % 2) + ix % 2 of the channel it reads
};

TapRead tap_read(Column c, uint tap) {
  const uint ky = tap / KW, kx = tap - ky * KW;
  int iy = c.iy + int(ky), ix = c.ix + int(kx);
  TapRead t;
  t.lim = (c.valid && iy >= 0 && iy < int(p.h) && ix >= 0 && ix < int(p.w)) ? p.cin : 0u;
  iy = clamp(iy, 0, int(p.h) - 1), ix = clamp(ix, 0, int(p.w) - 1);  // outside: any address, never read
  uint sy = uint(iy), sx = uint(ix);
  t.item = c.item, t.sub = 0u;
  if (MAP == 1u) {
    sy = reflect_index(iy - int(p.src_y), int(p.src_h));
    sx = reflect_index(ix - int(p.src_x), int(p.src_w));
  } else if (MAP == 2u) {
    sy = 2u * sy, sx = 2u * sx;  // plus the channel's (dy, dx) in gather_at
  } else if (MAP == 3u) {
    t.sub = 2u * (sy % 2u) + sx % 2u, sy /= 2u, sx /= 2u;
  }
  t.base = sy * p.src_w + sx;
  if (IG_PLAIN) t.base += p.in_off + c.item * p.in_bs;
  return t;
}

// Input channel ci (as the conv sees it) of a folded input at the column's tap.
float folded_at(TapRead t, uint ci) {
  uint piece = 0u, c0 = 0u;
  if (PIECES > 1u && ci >= PC1) piece = 1u, c0 = PC1;
  if (PIECES > 2u && ci >= PC2) piece = 2u, c0 = PC2;
  if (PIECES > 3u && ci >= PC3) piece = 3u, c0 = PC3;
  if (PIECES > 4u && ci >= PC4) piece = 4u, c0 = PC4;
  uint sc = ci - c0, at = t.base;
  if (MAP == 2u) at += ((sc % 4u) / 2u) * p.src_w + sc % 2u, sc /= 4u;
  else if (MAP == 3u) sc = 4u * sc + t.sub;
  at += sc * p.src_h * p.src_w;
  if (piece == 0u) return float(x0[p.in_off + t.item * p.in_bs + at]);
  uint base = p.piece_off[piece - 1u] + t.item * p.piece_bs[piece - 1u] + at;
  if (piece == 1u) return float(x1[base]);
  if (piece == 2u) return float(x2[base]);
  if (piece == 3u) return float(x3[base]);
  return float(x4[base]);
}

// X at input channel ci of the column's tap (zero past the input's channels or outside it).
float gather_at(TapRead t, uint ci) {
  float v = 0.0;
  if (ci < t.lim) v = IG_PLAIN ? float(x0[t.base + ci * (p.src_h * p.src_w)]) : folded_at(t, ci);
  return v;
}

#endif
