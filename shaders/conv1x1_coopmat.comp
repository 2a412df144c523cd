#version 450
// 1x1 conv as a GEMM on cooperative matrices (tensor cores), step 2 of the coopmat path (steps 1
// and 3 are conv1x1_pack and conv1x1_output): over one chunk of input channels,
//   M[co][t] (+)= sum over k < chunk_pad of W[co][c_begin + k] * V[k][t]
// W [cout_pad][cin_pad] and V [chunk_pad][pix_pad] float16 (padded rows and columns are zero), M
// [cout_pad][pix_pad] fp32 accumulators; all three row-major. ACCUM adds to M (chunks after the first).
// Workgroup (x, y): NW warps of WARP invocations side by side along the pixels; warp `wp` computes
// FM x FN fragments of lM x lN: output channels y*FM*lM + [0, FM*lM), pixels (x*NW + wp)*FN*lN +
// [0, FN*lN), stepping through the chunk lK input channels at a time.
// Two forms, real (GL_NV_cooperative_matrix) and emulated, with the same tiling, offsets and strides:
// coopmat.glsl.
#extension GL_EXT_shader_16bit_storage : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#extension GL_GOOGLE_include_directive : require
layout(constant_id = 0) const uint lM = 16;  // fragment rows (output channels)
layout(constant_id = 1) const uint lN = 8;   // fragment columns (pixels)
layout(constant_id = 2) const uint lK = 16;  // fragment depth (input channels)
layout(constant_id = 3) const uint FM = 1;   // fragments per warp along the output channels
layout(constant_id = 4) const uint FN = 4;   // fragments per warp along the pixels
layout(constant_id = 5) const uint NW = 4;   // warps per workgroup
layout(constant_id = 6) const uint WARP = 32;  // invocations per warp
layout(constant_id = 7) const uint ACCUM = 0;
layout(local_size_x_id = 8) in;                // NW * WARP
layout(push_constant) uniform P { uint chunk_pad, c_begin, cin_pad, pix_pad; } p;

layout(std430, binding = 0) readonly buffer V { float16_t v[]; };
layout(std430, binding = 1) readonly buffer W { float16_t w[]; };
layout(std430, binding = 2) buffer M { float m[]; };
#include "coopmat.glsl"

void main() {
  // Every invocation runs the same loops (no early exit): fragment ops and barriers stay uniform.
  const uint co0 = gl_WorkGroupID.y * FM * lM, t0 = (gl_WorkGroupID.x * NW + warp_id()) * FN * lN;
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) {
      if (ACCUM != 0u)
        cm_load_c(i, j, (co0 + i * lM) * p.pix_pad + t0 + j * lN, p.pix_pad);
      else
        cm_zero_c(i, j);
    }
  for (uint k = 0; k < p.chunk_pad; k += lK) {
    for (uint i = 0; i < FM; ++i) CM_LOAD_A(i, w, (co0 + i * lM) * p.cin_pad + p.c_begin + k, p.cin_pad);
    for (uint j = 0; j < FN; ++j) CM_LOAD_B(j, v, k * p.pix_pad + t0 + j * lN, p.pix_pad);
    cm_sync();  // emulated: the fragments are complete before any invocation reads them
    for (uint i = 0; i < FM; ++i)
      for (uint j = 0; j < FN; ++j) cm_mul_add(i, j);
    cm_sync();  // emulated: read before the next step overwrites them
  }
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) cm_store_c(i, j, (co0 + i * lM) * p.pix_pad + t0 + j * lN, p.pix_pad);
}
