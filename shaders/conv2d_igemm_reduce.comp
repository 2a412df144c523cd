#version 450
#extension GL_GOOGLE_include_directive : require
// The split-K epilogue of conv2d_igemm: the sum of the splits' partial sums, plus the bias, through
// the activation, plus the residual, into the output slice. One invocation per (phase, channel, pixel).
layout(local_size_x = 64) in;
layout(constant_id = 2) const uint STRIDE = 1;
layout(constant_id = 3) const uint ACT = 0;
layout(constant_id = 4) const float SLOPE = 0.0;
layout(constant_id = 5) const uint HAS_RES = 0;
layout(constant_id = 11) const uint MODE = 0;
#include "act.glsl"
#include "precision.glsl"
#define IG_BIAS 1
#define IG_RES 2
#define IG_OUT 3
#include "igemm_common.glsl"
layout(std430, binding = 0) readonly buffer Part { float part[]; };  // [split][phase][cout][npix]

void main() {
  const uint phases = MODE == 1u ? STRIDE * STRIDE : 1u;
  uint i = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  if (i >= phases * p.cout * igemm_npix()) return;
  uint gp = i % igemm_npix(), co = (i / igemm_npix()) % p.cout, ph = i / (igemm_npix() * p.cout);
  uint item, pix;
  if (!out_pixel(gp, uvec2(ph / STRIDE, ph % STRIDE), item, pix)) return;
  float v = bias[co];
  const uint splits = (igemm_kpad() + p.ksplit - 1u) / p.ksplit;
  for (uint s = 0; s < splits; ++s) v += part[((s * phases + ph) * p.cout + co) * igemm_npix() + gp];
  store_out(v, co, item, pix);
}
