#version 450
#extension GL_GOOGLE_include_directive : require
// conv2d as a tiled implicit GEMM, the GPU family (conv2d_igemm.cpp): C[co][p] = sum_k A[k][co] X(k, p),
// k = (ky*KW + kx)*cin_pad + ci over the taps and input channels (tap-major: a stage is one tap,
// igemm_gather.glsl), p over the output pixels of every item
// (NCHW, read and written in place through the slices' offsets: no im2col buffer, no pack pass).
// A workgroup computes a BM x BN tile of C; each step stages a BK-deep slice of A (the packed weights,
// vec4 loads) and of X (gathered from the input) in shared memory, double-buffered, while the next
// step's values are already loaded into registers. An invocation holds TM x TN accumulators (<= 64).
// MODE 1 runs one phase of a transposed conv as a stride-1 KH x KW conv (the sub-pixel form: the
// phase is gl_WorkGroupID.z % STRIDE^2, its output pixels lie STRIDE apart). The epilogue adds the
// bias (preloaded into the accumulators), the activation and the residual, and stores into the output
// slice; with PARTIAL (split-K) it stores the raw sums instead and conv2d_igemm_reduce finishes.
layout(local_size_x_id = 12) in;  // (BM / TM) * (BN / TN)
layout(constant_id = 0) const uint KH = 3;
layout(constant_id = 1) const uint KW = 3;
layout(constant_id = 2) const uint STRIDE = 1;
layout(constant_id = 3) const uint ACT = 0;
layout(constant_id = 4) const float SLOPE = 0.0;
layout(constant_id = 5) const uint HAS_RES = 0;
layout(constant_id = 6) const uint BM = 64;   // output channels per workgroup
layout(constant_id = 7) const uint BN = 64;   // output pixels per workgroup
layout(constant_id = 8) const uint BK = 16;   // reduction depth per stage
layout(constant_id = 9) const uint TM = 4;    // output channels per invocation (a multiple of 4)
layout(constant_id = 10) const uint TN = 4;   // output pixels per invocation (a multiple of 4)
layout(constant_id = 11) const uint MODE = 0;     // 0 conv, 1 a transposed conv's phases
layout(constant_id = 13) const uint PARTIAL = 0;  // 1: split-K partial sums into `part`
#include "act.glsl"
#include "precision.glsl"
#define IG_BIAS 2
#define IG_RES 3
#define IG_OUT 4
#include "igemm_common.glsl"

layout(std430, binding = 0) readonly buffer In0 { SFLOAT x0[]; };  // input piece 0 (the whole input unless folded)
layout(std430, binding = 1) readonly buffer Wt { SVEC4 wt[]; };  // [phase][kpad][co4]: vec4s of output channels
layout(std430, binding = 5) writeonly buffer Part { float part[]; };  // [split][phase][cout][npix]
layout(std430, binding = 6) readonly buffer In1 { SFLOAT x1[]; };
layout(std430, binding = 7) readonly buffer In2 { SFLOAT x2[]; };
layout(std430, binding = 8) readonly buffer In3 { SFLOAT x3[]; };
layout(std430, binding = 9) readonly buffer In4 { SFLOAT x4[]; };

const uint NT = (BM / TM) * (BN / TN);  // invocations
const uint TX = BN / TN, TY = BM / TM;  // invocations along the pixels and the channels
const uint AV = BK * BM / 4u;           // vec4s of an A stage
const uint LA = (AV + NT - 1u) / NT;    // of them per invocation
const uint LB = BK * BN / NT;           // X values per invocation (NT divides BN: the host checks)
// One vec4 of skew per row, so that rows one warp writes start on different banks.
const uint ASTR = BM / 4u + 1u, BSTR = BN / 4u + 1u;
shared vec4 sa[2u * BK * ASTR];
shared vec4 sb[2u * BK * BSTR];

#include "igemm_gather.glsl"

void main() {
  const uint tid = gl_LocalInvocationIndex, tx = tid % TX, ty = tid / TX;
  const uint n0 = gl_WorkGroupID.x * BN, m0 = gl_WorkGroupID.y * BM;
  const uint phases = MODE == 1u ? STRIDE * STRIDE : 1u;
  const uint ph = gl_WorkGroupID.z % phases, split = gl_WorkGroupID.z / phases;
  const uvec2 phase = uvec2(ph / STRIDE, ph % STRIDE);
  const uint kbeg = split * p.ksplit, kend = min(igemm_kpad(), kbeg + p.ksplit);
  const uint wbase = ph * igemm_kpad() * ((p.cout + 3u) / 4u);
  const uint cinp = igemm_kpad() / (KH * KW);  // a tap's rows: whole stages
  uint ld_tap = kbeg / cinp, ld_ci = kbeg % cinp;  // the next stage to load: its tap and first channel

  const uint bcol = tid % BN, brow0 = tid / BN;  // this invocation's X column and first row per stage
  Column col = column_of(n0 + bcol, phase);

  vec4 acc[TM][TN / 4u];
  for (uint i = 0; i < TM; ++i) {
    uint co = m0 + (i / 4u) * (BM / (TM / 4u)) + ty * 4u + i % 4u;
    float b0 = (PARTIAL == 0u && co < p.cout) ? bias[co] : 0.0;
    for (uint j = 0; j < TN / 4u; ++j) acc[i][j] = vec4(b0);
  }

  vec4 ra[LA];
  float rb[LB];
  // Loads stage k0 into registers; stores them into buffer `buf`.
#define LOAD_STAGE(k0)                                                                           \
  for (uint l = 0; l < LA; ++l) {                                                                \
    uint e = tid + l * NT, row = e / (BM / 4u), c4 = m0 / 4u + e % (BM / 4u);                     \
    ra[l] = (e < AV && c4 < ((p.cout + 3u) / 4u)) ? vec4(wt[wbase + ((k0) + row) * ((p.cout + 3u) / 4u) + c4]) : vec4(0.0);    \
  }                                                                                              \
  {                                                                                              \
    const TapRead t = tap_read(col, ld_tap);                                                     \
    for (uint l = 0; l < LB; ++l) rb[l] = gather_at(t, ld_ci + brow0 + l * (NT / BN));            \
    ld_ci += BK;                                                                                 \
    if (ld_ci == cinp) ld_ci = 0u, ++ld_tap;                                                     \
  }
#define STORE_STAGE(buf)                                                                         \
  for (uint l = 0; l < LA; ++l) {                                                                \
    uint e = tid + l * NT;                                                                       \
    if (e < AV) sa[((buf) * BK + e / (BM / 4u)) * ASTR + e % (BM / 4u)] = ra[l];                  \
  }                                                                                              \
  for (uint l = 0; l < LB; ++l) {                                                                \
    uint row = brow0 + l * (NT / BN);                                                            \
    sb[((buf) * BK + row) * BSTR + bcol / 4u][bcol % 4u] = rb[l];                                 \
  }

  const uint steps = kend > kbeg ? (kend - kbeg) / BK : 0u;
  if (steps > 0u) {
    LOAD_STAGE(kbeg)
    STORE_STAGE(0u)
  }
  barrier();
  for (uint s = 0; s < steps; ++s) {
    const uint cur = s & 1u;
    if (s + 1u < steps) { LOAD_STAGE(kbeg + (s + 1u) * BK) }  // in flight while this stage computes
    for (uint kk = 0; kk < BK; ++kk) {
      vec4 a[TM / 4u], b[TN / 4u];
      for (uint i = 0; i < TM / 4u; ++i) a[i] = sa[(cur * BK + kk) * ASTR + i * TY + ty];
      for (uint j = 0; j < TN / 4u; ++j) b[j] = sb[(cur * BK + kk) * BSTR + j * TX + tx];
      for (uint i = 0; i < TM; ++i)
        for (uint j = 0; j < TN / 4u; ++j) acc[i][j] += a[i / 4u][i % 4u] * b[j];
    }
    if (s + 1u < steps) { STORE_STAGE(1u - cur) }
    barrier();  // the other buffer is complete, and this one read, before the next stage
  }
  // Epilogue: each of the invocation's TN pixels once, then its TM channels.
  for (uint j = 0; j < TN; ++j) {
    uint gp = n0 + (j / 4u) * (BN / (TN / 4u)) + tx * 4u + j % 4u, item, pix;
    bool inside = out_pixel(gp, phase, item, pix);
    for (uint i = 0; i < TM; ++i) {
      uint co = m0 + (i / 4u) * (BM / (TM / 4u)) + ty * 4u + i % 4u;
      if (!inside || co >= p.cout) continue;
      float v = acc[i][j / 4u][j % 4u];
      if (PARTIAL != 0u) part[((split * phases + ph) * p.cout + co) * igemm_npix() + gp] = v;
      else store_out(v, co, item, pix);
    }
  }
}
