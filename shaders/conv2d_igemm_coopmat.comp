#version 450
// conv2d as a tiled implicit GEMM on cooperative matrices (tensor cores, fp16 operands, fp32
// accumulators), the fp16 GPU path `coopmat` (conv2d_coopmat.cpp): the same GEMM as conv2d_igemm,
// C[co][p] = sum_k A[co][k] X(k, p), with both operands staged in shared memory, double-buffered: each
// stage loads the next BK-deep slice of A (16-byte loads of the packed weights) and of X (gathered
// from the input, 8 pixels per 16-byte shared store) into registers while the fragments of this one
// multiply. Warp (wm, wn) of the WM x WN warps computes FM x FN fragments of lM x lN. The epilogue
// passes each C fragment through a per-warp shared tile: bias, activation, residual, saturating fp16
// store into the output slice (or, split-K, the raw sums into `part`). No scratch, one dispatch.
// Two forms, real (GL_NV_cooperative_matrix) and emulated, with the same tiling: coopmat.glsl.
#extension GL_EXT_shader_16bit_storage : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#extension GL_GOOGLE_include_directive : require
layout(constant_id = 0) const uint KH = 3;
layout(constant_id = 1) const uint KW = 3;
layout(constant_id = 2) const uint STRIDE = 1;
layout(constant_id = 3) const uint ACT = 0;
layout(constant_id = 4) const float SLOPE = 0.0;
layout(constant_id = 5) const uint HAS_RES = 0;
layout(constant_id = 6) const uint lM = 16;  // fragment rows (output channels)
layout(constant_id = 7) const uint lN = 8;   // fragment columns (pixels)
layout(constant_id = 8) const uint lK = 16;  // fragment depth = the stage depth BK
layout(constant_id = 9) const uint FM = 2;   // fragments per warp along the output channels
layout(constant_id = 10) const uint FN = 4;  // fragments per warp along the pixels
layout(constant_id = 11) const uint MODE = 0;
layout(local_size_x_id = 12) in;             // NW * WARP
layout(constant_id = 13) const uint PARTIAL = 0;
layout(constant_id = 14) const uint WARP = 32;
layout(constant_id = 15) const uint WM = 2;  // warps along the output channels
layout(constant_id = 16) const uint WN = 2;  // warps along the pixels
const uint NW = WM * WN;
#include "act.glsl"
#define VKU_FP16  // fp16 operands, input, output and residual (precision.glsl, via igemm_common.glsl)
#define IG_BIAS 2
#define IG_RES 3
#define IG_OUT 4
#include "igemm_common.glsl"

layout(std430, binding = 0) readonly buffer In0 { float16_t x0[]; };  // input piece 0 (the whole input unless folded)
layout(std430, binding = 1) readonly buffer Wt { uvec4 wt[]; };  // [cout_pad][kpad] halves, 8 a word
layout(std430, binding = 5) writeonly buffer Part { float part[]; };
layout(std430, binding = 6) readonly buffer In1 { float16_t x1[]; };
layout(std430, binding = 7) readonly buffer In2 { float16_t x2[]; };
layout(std430, binding = 8) readonly buffer In3 { float16_t x3[]; };
layout(std430, binding = 9) readonly buffer In4 { float16_t x4[]; };
#include "igemm_gather.glsl"
#include "coopmat.glsl"

const uint BM = WM * FM * lM, BN = WN * FN * lN, BK = lK, NT = NW * WARP;
const uint ASTR = BK / 8u + 1u;  // uvec4s per A row (one output channel), one of skew
const uint BSTR = BN / 8u + 1u;  // uvec4s per X row (one reduction step), one of skew
shared uvec4 sa[2u * BM * ASTR];
shared uvec4 sb[2u * BK * BSTR];
shared float sc[NW * lM * lN];  // each warp's C fragment on its way to the output
const uint LA = (BM * BK / 8u + NT - 1u) / NT;  // A words per invocation and stage
const uint XU = BK * BN / 8u;                   // 8-pixel X units per stage
const uint LX = (XU + NT - 1u) / NT;

void main() {
  const uint tid = gl_LocalInvocationIndex, n0 = gl_WorkGroupID.x * BN, m0 = gl_WorkGroupID.y * BM;
  const uint split = gl_WorkGroupID.z, kbeg = split * p.ksplit, kend = min(igemm_kpad(), kbeg + p.ksplit);
  const uint wm = warp_id() / WN, wn = warp_id() % WN;
  // This invocation's 8 X columns (the same for every stage and every unit it loads).
  const uint g8 = tid % (BN / 8u);
  Column cols[8];
  for (uint c = 0; c < 8u; ++c) cols[c] = column_of(n0 + g8 * 8u + c, uvec2(0));
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) cm_zero_c(i, j);
  const uint cinp = igemm_kpad() / (KH * KW);      // a tap's rows (tap-major K: a stage is one tap)
  uint ld_tap = kbeg / cinp, ld_ci = kbeg % cinp;  // the next stage to load: its tap and first channel

  uvec4 ra[LA], rx[LX];
#define LOAD_STAGE(k0)                                                                            \
  for (uint l = 0; l < LA; ++l) {                                                                 \
    uint e = tid + l * NT, co = m0 + e / (BK / 8u);                                               \
    ra[l] = (e < BM * BK / 8u && co < (p.cout + 3u) / 4u * 4u) ? wt[(co * igemm_kpad() + (k0)) / 8u + e % (BK / 8u)] : uvec4(0); \
  }                                                                                               \
  {                                                                                               \
    TapRead t[8];                                                                                 \
    for (uint c = 0; c < 8u; ++c) t[c] = tap_read(cols[c], ld_tap);                               \
    for (uint l = 0; l < LX; ++l) {                                                               \
      uint ci = ld_ci + (tid + l * NT) / (BN / 8u);                                               \
      for (uint c = 0; c < 4u; ++c)                                                               \
        rx[l][c] = packFloat2x16(f16vec2(gather_at(t[2u * c], ci), gather_at(t[2u * c + 1u], ci))); \
    }                                                                                             \
    ld_ci += BK;                                                                                  \
    if (ld_ci == cinp) ld_ci = 0u, ++ld_tap;                                                      \
  }
#define STORE_STAGE(buf)                                                                          \
  for (uint l = 0; l < LA; ++l) {                                                                 \
    uint e = tid + l * NT;                                                                        \
    if (e < BM * BK / 8u) sa[((buf) * BM + e / (BK / 8u)) * ASTR + e % (BK / 8u)] = ra[l];         \
  }                                                                                               \
  for (uint l = 0; l < LX; ++l) {                                                                 \
    uint u = tid + l * NT;                                                                        \
    if (u < XU) sb[((buf) * BK + u / (BN / 8u)) * BSTR + u % (BN / 8u)] = rx[l];                  \
  }

  const uint steps = kend > kbeg ? (kend - kbeg) / BK : 0u;
  if (steps > 0u) {
    LOAD_STAGE(kbeg)
    STORE_STAGE(0u)
  }
  barrier();
  for (uint s = 0; s < steps; ++s) {
    const uint cur = s & 1u;
    if (s + 1u < steps) { LOAD_STAGE(kbeg + (s + 1u) * BK) }
    for (uint i = 0; i < FM; ++i) CM_LOAD_A_U4(i, sa, (cur * BM + (wm * FM + i) * lM) * ASTR, ASTR);
    for (uint j = 0; j < FN; ++j) CM_LOAD_B_U4(j, sb, cur * BK * BSTR + ((wn * FN + j) * lN) / 8u, BSTR);
    cm_sync();  // emulated: the fragments are complete before any invocation reads them
    for (uint i = 0; i < FM; ++i)
      for (uint j = 0; j < FN; ++j) cm_mul_add(i, j);
    if (s + 1u < steps) { STORE_STAGE(1u - cur) }
    barrier();  // the other buffer complete, this one (and the emulated fragments) read
  }

  // Epilogue, one fragment at a time through this warp's shared tile.
  const uint tile = warp_id() * lM * lN;
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) {
      CM_STORE_C(i, j, sc, tile, lN);
      barrier();  // the fragment is in shared memory before its lanes read it
      for (uint e = cm_lane(); e < lM * lN; e += WARP) {
        uint co = m0 + (wm * FM + i) * lM + e / lN, gp = n0 + (wn * FN + j) * lN + e % lN, item, pix;
        if (co >= p.cout || !out_pixel(gp, uvec2(0), item, pix)) continue;
        float v = sc[tile + e];
        if (PARTIAL != 0u) part[(split * p.cout + co) * igemm_npix() + gp] = v;
        else store_out(v + bias[co], co, item, pix);
      }
      barrier();  // read before the next fragment overwrites the tile
    }
}
