#version 450
// KS x KS stride-1 conv with pad KS/2 (3x3 and 5x5) as an implicit GEMM on cooperative matrices
// (tensor cores), the GEMM step of the coopmat path (conv1x1_output is the epilogue):
//   M[co][t] = sum over kk < kpad of W[co][kk] * X(kk, t),  kk = ci*KS*KS + ky*KS + kx,
//   X(kk, t) = input (n, ci, y + ky - KS/2, x + kx - KS/2) of output pixel t = (n, y, x), zero outside
// W [cout_pad][kpad] float16 (zero-padded), M [cout_pad][pix_pad] fp32, row-major. Each step of lK
// columns of W, the workgroup gathers X's lK rows for its NW*FN*lN pixels into shared memory (im2col,
// never stored to global memory); warp `wp` of workgroup (x, y) computes FM x FN fragments: output
// channels y*FM*lM + [0, FM*lM), pixels (x*NW + wp)*FN*lN + [0, FN*lN).
// Two forms, real (GL_NV_cooperative_matrix) and emulated, with the same tiling: coopmat.glsl.
#extension GL_EXT_shader_16bit_storage : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#extension GL_GOOGLE_include_directive : require
layout(constant_id = 0) const uint lM = 16;  // fragment rows (output channels)
layout(constant_id = 1) const uint lN = 8;   // fragment columns (pixels)
layout(constant_id = 2) const uint lK = 16;  // fragment depth (kernel taps x input channels)
layout(constant_id = 3) const uint FM = 1;   // fragments per warp along the output channels
layout(constant_id = 4) const uint FN = 4;   // fragments per warp along the pixels
layout(constant_id = 5) const uint NW = 4;   // warps per workgroup
layout(constant_id = 6) const uint WARP = 32;  // invocations per warp
layout(local_size_x_id = 8) in;                // NW * WARP (constant 7, ACCUM of the 1x1 GEMM, unused)
layout(constant_id = 9) const uint KS = 3;     // kernel side (odd; pad KS / 2)
layout(push_constant) uniform P { uint in_off, in_bs, cin, h, w, npix, kpad, pix_pad; } p;

layout(std430, binding = 0) readonly buffer In { float16_t x[]; };
layout(std430, binding = 1) readonly buffer W { float16_t wt[]; };
layout(std430, binding = 2) buffer M { float m[]; };
#include "coopmat.glsl"

const uint WGP = NW * FN * lN;        // pixels per workgroup (a multiple of 8)
shared uvec4 cols[lK * WGP / 8u];     // the im2col tile [lK][WGP], 8 halves per uvec4 (16-byte aligned rows)

float tap(uint kk, uint t) {
  if (kk >= KS * KS * p.cin || t >= p.npix) return 0.0;
  uint plane = p.h * p.w, ci = kk / (KS * KS), r = kk % (KS * KS), q = t % plane;
  int y = int(q / p.w) + int(r / KS) - int(KS / 2u), xx = int(q % p.w) + int(r % KS) - int(KS / 2u);
  if (y < 0 || y >= int(p.h) || xx < 0 || xx >= int(p.w)) return 0.0;
  return float(x[p.in_off + (t / plane) * p.in_bs + ci * plane + uint(y) * p.w + uint(xx)]);
}

void main() {
  // Every invocation runs the same loops (no early exit): fragment ops and barriers stay uniform.
  const uint co0 = gl_WorkGroupID.y * FM * lM, wt0 = gl_WorkGroupID.x * WGP, t0 = wt0 + warp_id() * FN * lN;
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) cm_zero_c(i, j);
  for (uint k0 = 0; k0 < p.kpad; k0 += lK) {
    barrier();  // the previous step's fragments are loaded before the tile is overwritten
    for (uint g = gl_LocalInvocationIndex; g < lK * WGP / 8u; g += NW * WARP) {
      uint kk = k0 + g / (WGP / 8u), t = wt0 + (g % (WGP / 8u)) * 8u;
      uvec4 word;
      for (uint c = 0; c < 4u; ++c) word[c] = packFloat2x16(f16vec2(tap(kk, t + 2u * c), tap(kk, t + 2u * c + 1u)));
      cols[g] = word;
    }
    barrier();  // with workgroup-memory semantics: the columns are visible (cm_sync in coopmat.glsl says why no memoryBarrierShared)
    for (uint i = 0; i < FM; ++i) CM_LOAD_A(i, wt, (co0 + i * lM) * p.kpad + k0, p.kpad);
    for (uint j = 0; j < FN; ++j) CM_LOAD_B_U4(j, cols, (warp_id() * FN * lN + j * lN) / 8u, WGP / 8u);
    cm_sync();  // emulated: the fragments are complete before any invocation reads them
    for (uint i = 0; i < FM; ++i)
      for (uint j = 0; j < FN; ++j) cm_mul_add(i, j);
    cm_sync();  // emulated: read before the next step overwrites them
  }
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) cm_store_c(i, j, (co0 + i * lM) * p.pix_pad + t0 + j * lN, p.pix_pad);
}
