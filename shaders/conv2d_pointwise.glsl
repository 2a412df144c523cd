// conv2d, the pointwise algorithm (1x1 stride 1, pad 0): one dispatch per block of COB output
// channels and chunk of CK input channels reads the input slice where it lies ([cin][pixels] per
// batch item) and writes the output slice; no packing, no scratch. Each invocation computes PX
// pixels (lanes take consecutive pixels, so a lane group's input gather covers adjacent values)
// for COB channels. The input-channel loop is unrolled whole (CK is a specialization constant), so
// every weight index is a compile-time constant: llvmpipe then loads each weight once as a scalar
// and broadcasts it, where a loop-indexed uniform load is a gather per lane (docs/kernels.md).
// Chunks after the first add to the raw sums already in the output; the last applies the
// activation and the residual. PX x COB accumulators are sized to stay in registers.
// The body of conv2d_pointwise.comp (input in a storage buffer), conv2d_pointwise_texel.comp
// (input through a uniform texel buffer, DIRECT_TEXEL_INPUT; see direct_input.glsl) and
// conv2d_pointwise_pairs.comp (the same in pixel pairs, POINTWISE_PAIRS).
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint ACT = 0;
layout(constant_id = 1) const float SLOPE = 0.0;
layout(constant_id = 2) const uint HAS_RES = 0;
layout(constant_id = 3) const uint PX = 1;       // pixels (pairs: pixel pairs) per invocation, 64 apart
layout(constant_id = 4) const uint COB = 12;     // output channels per invocation (the weight slab's row)
layout(constant_id = 5) const uint CK = 64;      // input channels of this dispatch, unrolled
layout(constant_id = 6) const uint FIRST = 1;    // first input-channel chunk: start from the bias
layout(constant_id = 7) const uint LAST = 1;     // last chunk: activation and residual
layout(constant_id = 8) const uint SLAB = 4096;  // 16-byte entries of the bound weight slab
#include "act.glsl"
#include "precision.glsl"
#include "direct_input.glsl"
layout(std430, binding = 2) readonly buffer Bias { float bias[]; };
layout(std430, binding = 3) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = 4) buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint plane, cout, co0;  // plane: pixels per channel (h * w); co0: first output channel of the block
} p;

// POINTWISE_PAIRS (conv2d_pointwise_pairs.comp): the texel view is RG, one fetch per pixel pair,
// which llvmpipe loads as one 8-byte value per lane instead of gathering two scalars; the host
// takes it only where the plane, offsets and batch stride are even (no pair straddles channels).
#ifdef POINTWISE_PAIRS
const uint NP = 2u;
vec2 load_unit(uint i) { return texelFetch(xin, int(i)).rg; }
#else
const uint NP = 1u;
vec2 load_unit(uint i) { return vec2(load_input(i), 0.0); }
#endif

// Weight i of the slab [CK][COB] (constant i: one scalar load).
float weight1(uint i) {
  vec4 q = weight4(i >> 2u);
  return q[i & 3u];
}

void main() {
  uint n = gl_WorkGroupID.z;
  uint wg = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
  uint base = wg * 64u * PX + gl_LocalInvocationID.x;
  // Units: pixels (NP = 1) or pixel pairs (NP = 2). Out-of-range units read a clamped one and are
  // never stored (no divergent loop).
  uint units = p.plane / NP;
  uint unit[PX];
  [[unroll]] for (uint j = 0; j < PX; ++j) unit[j] = min(base + j * 64u, units - 1u);
  uint ob = p.out_off + n * p.out_bs;
  float acc[PX][NP][COB];
  [[unroll]] for (uint c = 0; c < COB; ++c) {
    uint co = min(p.co0 + c, p.cout - 1u);
    [[unroll]] for (uint j = 0; j < PX; ++j)
      [[unroll]] for (uint k = 0; k < NP; ++k)
        acc[j][k][c] = FIRST != 0u ? bias[co] : float(y[ob + co * p.plane + unit[j] * NP + k]);
  }
  uint ib = p.in_off + n * p.in_bs;
  [[unroll]] for (uint ci = 0; ci < CK; ++ci) {
    uint cb = (ib + ci * p.plane) / NP;
    vec2 xv[PX];
    [[unroll]] for (uint j = 0; j < PX; ++j) xv[j] = load_unit(cb + unit[j]);
    [[unroll]] for (uint c = 0; c < COB; ++c) {
      float wv = weight1(ci * COB + c);
      [[unroll]] for (uint j = 0; j < PX; ++j)
        [[unroll]] for (uint k = 0; k < NP; ++k) acc[j][k][c] = fma(xv[j][k], wv, acc[j][k][c]);
    }
  }
  uint rb = p.res_off + n * p.res_bs;
  [[unroll]] for (uint j = 0; j < PX; ++j) {
    if (base + j * 64u >= units) continue;
    [[unroll]] for (uint k = 0; k < NP; ++k)
      [[unroll]] for (uint c = 0; c < COB; ++c) {
        uint co = p.co0 + c;
        if (co >= p.cout) continue;
        uint o = co * p.plane + (base + j * 64u) * NP + k;
        float v = acc[j][k][c];
        if (LAST != 0u) {
          v = act(v);
          if (HAS_RES != 0u) v += float(res[rb + o]);
        }
        y[ob + o] = to_s(v);
      }
  }
}
