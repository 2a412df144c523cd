// The implicit GEMM's X (im2col, never stored): value (k, gp) read from the input in place, for
// conv2d_igemm and conv2d_igemm_coopmat. The includer declares KH, KW, STRIDE, MODE, the push
// constants (igemm_common.glsl) and the input buffer `x`.
#ifndef VKU_IGEMM_GATHER_GLSL
#define VKU_IGEMM_GATHER_GLSL
// The invocation's fixed column of X: where its output pixel's window starts in the input.
struct Column {
  bool valid;
  uint item;    // x index of (batch item, channel 0, 0, 0)
  int iy, ix;   // input row and column of tap (0, 0)
};

Column column_of(uint gp, uvec2 phase) {
  Column c;
  c.valid = gp < p.npix;
  uint g = min(gp, p.npix - 1u), gplane = p.gh * p.gw, r = g % gplane;
  c.item = p.in_off + (g / gplane) * p.in_bs;
  // A conv: pixel (oy, ox) reads from (oy, ox) * STRIDE - pad. A transposed conv's phase (py, px):
  // pixel (qy, qx) reads from (qy, qx) + (phase + pad) / STRIDE - (KH - 1, KW - 1) (conv_transpose2d.cpp
  // packs each phase's taps flipped to match).
  ivec2 base = MODE == 1u ? ivec2((phase + uvec2(p.pad)) / STRIDE) - ivec2(KH - 1u, KW - 1u) : -ivec2(int(p.pad));
  const uint step = MODE == 1u ? 1u : STRIDE;
  c.iy = int((r / p.gw) * step) + base.x;
  c.ix = int((r % p.gw) * step) + base.y;
  return c;
}

float gather(Column c, uint k) {
  uint ci = k / (KH * KW), t = k - ci * (KH * KW), ky = t / KW, kx = t - ky * KW;
  int iy = c.iy + int(ky), ix = c.ix + int(kx);
  bool ok = c.valid && k < p.kdim && iy >= 0 && iy < int(p.h) && ix >= 0 && ix < int(p.w);
  float v = 0.0;
  if (ok) v = float(x[c.item + ci * p.h * p.w + uint(iy) * p.w + uint(ix)]);
  return v;
}

#endif
