// What conv2d_igemm, conv2d_igemm_coopmat and conv2d_igemm_reduce share: the push constants, where a
// GEMM pixel lands in the output slice, and the epilogue (bias added by the caller, then activation,
// scale, residual, saturating store). The includer declares the spec constants STRIDE, ACT, SLOPE,
// HAS_RES and MODE and defines IG_BIAS, IG_RES and IG_OUT, the bindings of the bias, residual and
// output buffers.
#ifndef VKU_IGEMM_COMMON_GLSL
#define VKU_IGEMM_COMMON_GLSL
#include "precision.glsl"

layout(constant_id = 23) const float SCALE = 1.0;  // the activation's output times this (the flow's 100 tanh)

layout(push_constant) uniform P {
  uint in_off, in_bs;                 // input piece 0: element offset, batch stride
  uint res_off, res_bs, out_off, out_bs;
  uint h, w;                          // the conv's input extent (folded: as the conv sees it)
  uint cout, pad;                     // pad: the conv's, or the transposed conv's (MODE 1)
  uint kpad, cin, n;                  // reduction length (KH KW cin_pad, tap-major), input channels, batch items
  uint gh, gw, ksplit;                // GEMM pixel grid per item (MODE 1: per phase), reduction per split
  uint out_h, out_w, crop_y, crop_x;  // the output slice's extent, and its origin in the conv's output
  uint src_h, src_w, src_y, src_x;    // folded input: the pieces' extent, their origin in the padded input
  uint piece_off[4], piece_bs[4];     // input pieces 1-4
} p;

uint igemm_npix() { return p.n * p.gh * p.gw; }
uint igemm_kpad() { return p.kpad; }  // whole stages of the deepest tile

layout(std430, binding = IG_BIAS) readonly buffer Bias { float bias[]; };
layout(std430, binding = IG_RES) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = IG_OUT) writeonly buffer Out { SFLOAT y[]; };

// GEMM pixel gp of phase (py, px) as (batch item, offset in the output slice's plane); false when it
// lies outside the slice (past the grid, or cropped off).
bool out_pixel(uint gp, uvec2 phase, out uint item, out uint pix) {
  uint g = min(gp, igemm_npix() - 1u), gplane = p.gh * p.gw, r = g % gplane;
  item = g / gplane;
  uint oy = r / p.gw, ox = r % p.gw;
  if (MODE == 1u) oy = oy * STRIDE + phase.x, ox = ox * STRIDE + phase.y;
  int sy = int(oy) - int(p.crop_y), sx = int(ox) - int(p.crop_x);
  pix = uint(max(sy, 0)) * p.out_w + uint(max(sx, 0));
  return gp < igemm_npix() && sy >= 0 && sy < int(p.out_h) && sx >= 0 && sx < int(p.out_w);
}

// v (the sum plus bias) through the activation and scale, plus the residual, into output channel co.
void store_out(float v, uint co, uint item, uint pix) {
  uint plane = p.out_h * p.out_w;
  v = SCALE * act(v);
  if (HAS_RES != 0u) v += float(res[p.res_off + item * p.res_bs + co * plane + pix]);
  y[p.out_off + item * p.out_bs + co * plane + pix] = to_s(v);
}
#endif
