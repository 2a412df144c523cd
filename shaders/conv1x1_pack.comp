#version 450
// 1x1 conv as a GEMM, step 1: copy a chunk of input channels into the GEMM's aligned layout
// [chunk][pix_pad], pixels of all batch items in a row (t = n * plane + p), four per invocation
// (one vec4 store); pixels past the end are 0, and so are rows cl >= c_valid (the coopmat path pads
// the chunk to whole 16-channel fragments; the GEMM path packs only real channels: c_valid = chunk).
// fp16 variant: input and V as float16 (a copy: no scaling).
#extension GL_GOOGLE_include_directive : require
#include "precision.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) writeonly buffer V { SVEC4 v[]; };
layout(push_constant) uniform P { uint in_off, in_bs, plane, npix, pix_pad, c_begin, c_valid; } p;
void main() {
  uint g = gl_GlobalInvocationID.x, cl = gl_GlobalInvocationID.y;
  if (g * 4u >= p.pix_pad) return;
  uint ci = p.c_begin + cl;
  vec4 r = vec4(0.0);
  if (cl < p.c_valid)
    for (uint k = 0; k < 4u; ++k) {
      uint t = min(g * 4u + k, p.npix - 1u);
      float val = float(x[p.in_off + (t / p.plane) * p.in_bs + ci * p.plane + t % p.plane]);
      r[k] = g * 4u + k < p.npix ? val : 0.0;
    }
  v[cl * (p.pix_pad / 4u) + g] = SVEC4(r);
}
