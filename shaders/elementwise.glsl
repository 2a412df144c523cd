// Elementwise ops on slices, the body of elementwise.comp (storage-buffer inputs) and
// elementwise_texel.comp (ELEMENTWISE_TEXEL_INPUT: the inputs through uniform texel buffers, R32 /
// R16 in fp16; on llvmpipe a texel fetch is one gather, a storage-buffer load a loop over the lanes).
// OP 0 copy: a; 1 add: a + b; 2 scale_act: scale * act(a); 3 blend: m*a + (1-m)*b with m one
// channel broadcast over channels; 4 clamp01: clamp(a, 0, 1).
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint OP = 0;
layout(constant_id = 1) const uint ACT = 0;
layout(constant_id = 2) const float SLOPE = 0.0;
#include "act.glsl"
// All operands in the variant's storage type, arithmetic in fp32.
#ifdef ELEMENTWISE_TEXEL_INPUT
layout(binding = 0) uniform samplerBuffer a;
layout(binding = 1) uniform samplerBuffer b;
layout(binding = 2) uniform samplerBuffer m;
#define LOAD(t, i) texelFetch(t, int(i)).r
#else
layout(std430, binding = 0) readonly buffer A { SFLOAT a_[]; };
layout(std430, binding = 1) readonly buffer B { SFLOAT b_[]; };
layout(std430, binding = 2) readonly buffer M { SFLOAT m_[]; };
#define LOAD(t, i) float(t##_[i])
#endif
layout(std430, binding = 3) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint a_off, a_bs, b_off, b_bs, m_off, m_bs, out_off, out_bs, c, plane;
  float scale;
} p;
void main() {
  // Four elements an invocation, a grid's width apart (so that neighbouring lanes read neighbouring
  // elements): llvmpipe's per-invocation cost outweighs one element's. The host sizes the grid to a
  // quarter of the plane, so four unrolled steps cover it without a loop's exit test per step.
  uint c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z, stride = gl_NumWorkGroups.x * 64u;
  if (c >= p.c) return;
  [[unroll]] for (uint k = 0u; k < 4u; ++k) {
    uint i = gl_GlobalInvocationID.x + k * stride;
    if (i >= p.plane) break;
    uint e = c * p.plane + i;
    float va = LOAD(a, p.a_off + n * p.a_bs + e);
    float v;
    if (OP == 1u) v = va + LOAD(b, p.b_off + n * p.b_bs + e);
    else if (OP == 2u) v = p.scale * act(va);
    else if (OP == 3u) {
      float mm = LOAD(m, p.m_off + n * p.m_bs + i);
      v = mm * va + (1.0 - mm) * LOAD(b, p.b_off + n * p.b_bs + e);
    } else if (OP == 4u) v = clamp(va, 0.0, 1.0);
    else v = va;
    y[p.out_off + n * p.out_bs + e] = to_s(v);
  }
}
