#version 450
#extension GL_GOOGLE_include_directive : require
// 1x1 conv as a GEMM, step 3: M [cout_pad][pix_pad] plus bias, the fused activation and the
// optional residual, written into the output slice; four pixels of one channel per invocation.
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint ACT = 0;
layout(constant_id = 1) const float SLOPE = 0.0;
layout(constant_id = 2) const uint HAS_RES = 0;
#include "act.glsl"
#include "precision.glsl"
// fp16 variant: M stays fp32, residual and output float16.
layout(std430, binding = 0) readonly buffer M { vec4 m[]; };
layout(std430, binding = 1) readonly buffer Bias { float bias[]; };
layout(std430, binding = 2) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = 3) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P { uint res_off, res_bs, out_off, out_bs, plane, npix, pix_pad; } p;
void main() {
  uint g = gl_GlobalInvocationID.x, co = gl_GlobalInvocationID.y;
  if (g * 4u >= p.npix) return;
  vec4 v = m[co * (p.pix_pad / 4u) + g];
  float b = bias[co];
  for (uint k = 0; k < 4u; ++k) {
    uint t = g * 4u + k;
    if (t >= p.npix) continue;
    uint n = t / p.plane, o = co * p.plane + t % p.plane;
    float r = act(v[k] + b);
    if (HAS_RES != 0u) r += float(res[p.res_off + n * p.res_bs + o]);
    y[p.out_off + n * p.out_bs + o] = to_s(r);
  }
}
