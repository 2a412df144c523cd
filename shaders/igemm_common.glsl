// What conv2d_igemm and conv2d_igemm_reduce share: the push constants, where a GEMM pixel lands in
// the output, and the epilogue (bias added by the caller, then activation, residual, saturating
// store). The includer declares the spec constants STRIDE, ACT, SLOPE, HAS_RES, MODE and defines
// IG_BIAS, IG_RES and IG_OUT, the bindings of the bias, residual and output buffers.
#ifndef VKU_IGEMM_COMMON_GLSL
#define VKU_IGEMM_COMMON_GLSL
#include "precision.glsl"

layout(push_constant) uniform P {
  uint in_off, in_bs, res_off, res_bs, out_off, out_bs;  // slices: element offsets, batch strides
  uint cin, h, w, cout, oh, ow, pad;  // pad: the conv's, or the transposed conv's (MODE 1)
  uint kdim, kpad, co4;               // reduction length, padded to BK, vec4s of output channels
  uint npix, gh, gw;                  // GEMM pixels (items x gh x gw; MODE 1: per phase)
  uint ksplit, nsplit;                // reduction per split (a multiple of BK), splits
} p;

layout(std430, binding = IG_BIAS) readonly buffer Bias { float bias[]; };
layout(std430, binding = IG_RES) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = IG_OUT) writeonly buffer Out { SFLOAT y[]; };

// GEMM pixel gp of phase (py, px) as (batch item, offset in the output plane); false outside it.
bool out_pixel(uint gp, uvec2 phase, out uint item, out uint pix) {
  uint g = min(gp, p.npix - 1u), gplane = p.gh * p.gw, r = g % gplane;
  item = g / gplane;
  uint oy = r / p.gw, ox = r % p.gw;
  if (MODE == 1u) oy = oy * STRIDE + phase.x, ox = ox * STRIDE + phase.y;
  pix = oy * p.ow + ox;
  return gp < p.npix && oy < p.oh && ox < p.ow;
}

// v (the sum plus bias) through the activation, plus the residual, into output channel co.
void store_out(float v, uint co, uint item, uint pix) {
  uint plane = p.oh * p.ow;
  v = act(v);
  if (HAS_RES != 0u) v += float(res[p.res_off + item * p.res_bs + co * plane + pix]);
  y[p.out_off + item * p.out_bs + co * plane + pix] = to_s(v);
}
#endif
