#version 450
// 1x1 conv as a GEMM on cooperative matrices (tensor cores), step 2 of the coopmat path (steps 1
// and 3 are conv1x1_pack and conv1x1_output): over one chunk of input channels,
//   M[co][t] (+)= sum over k < chunk_pad of W[co][c_begin + k] * V[k][t]
// W [cout_pad][cin_pad] and V [chunk_pad][pix_pad] float16 (padded rows and columns are zero), M
// [cout_pad][pix_pad] fp32 accumulators; all three row-major. ACCUM adds to M (chunks after the first).
// Workgroup (x, y): NW warps of WARP invocations side by side along the pixels; warp `wp` computes
// FM x FN fragments of lM x lN: output channels y*FM*lM + [0, FM*lM), pixels (x*NW + wp)*FN*lN +
// [0, FN*lN), stepping through the chunk lK input channels at a time.
// One source, two forms (cmake/Shaders.cmake): conv1x1_coopmat on GL_NV_cooperative_matrix (a warp is
// one subgroup, so the device's subgroup size must be WARP), and conv1x1_coopmat_emulated
// (-DVKU_COOPMAT_EMULATE): a warp is WARP consecutive invocations; the A and B fragments live in shared
// memory, C in registers (fixed elements per invocation), and each fragment op is plain loads and fp32
// FMAs of the fp16 operands, with the same tiling, offsets and strides: lavapipe tests every index.
#extension GL_EXT_shader_16bit_storage : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
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

#ifdef VKU_COOPMAT_EMULATE
layout(std430, binding = 0) readonly buffer V { float16_t v[]; };
layout(std430, binding = 1) readonly buffer W { float16_t w[]; };
layout(std430, binding = 2) buffer M { float m[]; };
shared float16_t sa[NW * FM * lM * lK];
shared float16_t sb[NW * FN * lK * lN];
const uint CPER = (lM * lN) / WARP;  // C elements per invocation and fragment (lM*lN % WARP == 0)
float cr[FM * FN * CPER];            // element e = lane + q*WARP of fragment (i, j) is cr[(i*FN + j)*CPER + q]
uint warp_id() { return gl_LocalInvocationIndex / WARP; }
uint lane() { return gl_LocalInvocationIndex % WARP; }
void sync() { memoryBarrierShared(); barrier(); }
// Row-major loads and stores: element (r, c) at buf[element + r*stride + c], stride in elements.
void load_a(uint i, uint element, uint stride) {
  uint base = (warp_id() * FM + i) * lM * lK;
  for (uint e = lane(); e < lM * lK; e += WARP) sa[base + e] = w[element + (e / lK) * stride + e % lK];
}
void load_b(uint j, uint element, uint stride) {
  uint base = (warp_id() * FN + j) * lK * lN;
  for (uint e = lane(); e < lK * lN; e += WARP) sb[base + e] = v[element + (e / lN) * stride + e % lN];
}
void zero_c(uint i, uint j) {
  for (uint q = 0; q < CPER; ++q) cr[(i * FN + j) * CPER + q] = 0.0;
}
void load_c(uint i, uint j, uint element, uint stride) {
  for (uint q = 0; q < CPER; ++q) {
    uint e = lane() + q * WARP;
    cr[(i * FN + j) * CPER + q] = m[element + (e / lN) * stride + e % lN];
  }
}
void store_c(uint i, uint j, uint element, uint stride) {
  for (uint q = 0; q < CPER; ++q) {
    uint e = lane() + q * WARP;
    m[element + (e / lN) * stride + e % lN] = cr[(i * FN + j) * CPER + q];
  }
}
void mul_add(uint i, uint j) {  // C(i, j) += A(i) B(j)
  uint a = (warp_id() * FM + i) * lM * lK, b = (warp_id() * FN + j) * lK * lN;
  for (uint q = 0; q < CPER; ++q) {
    uint e = lane() + q * WARP, r = e / lN, c = e % lN;
    float acc = cr[(i * FN + j) * CPER + q];
    for (uint k = 0; k < lK; ++k) acc = fma(float(sa[a + r * lK + k]), float(sb[b + k * lN + c]), acc);
    cr[(i * FN + j) * CPER + q] = acc;
  }
}
#else
#extension GL_NV_cooperative_matrix : require
#extension GL_KHR_memory_scope_semantics : require
#extension GL_KHR_shader_subgroup_basic : require
layout(std430, binding = 0) buffer V { float16_t v[]; };
layout(std430, binding = 1) buffer W { float16_t w[]; };
layout(std430, binding = 2) buffer M { float m[]; };
fcoopmatNV<16, gl_ScopeSubgroup, lM, lK> fa[FM];
fcoopmatNV<16, gl_ScopeSubgroup, lK, lN> fb[FN];
fcoopmatNV<32, gl_ScopeSubgroup, lM, lN> fc[FM * FN];
uint warp_id() { return gl_SubgroupID; }
void sync() {}  // the fragments are the subgroup's registers
// coopMatLoadNV/StoreNV with colMajor = false (row-major): element (r, c) at buf[element + r*stride + c],
// element and stride counted in the buffer's scalars (float16_t for W and V, float for M).
void load_a(uint i, uint element, uint stride) { coopMatLoadNV(fa[i], w, element, stride, false); }
void load_b(uint j, uint element, uint stride) { coopMatLoadNV(fb[j], v, element, stride, false); }
void zero_c(uint i, uint j) { fc[i * FN + j] = fcoopmatNV<32, gl_ScopeSubgroup, lM, lN>(0.0); }
void load_c(uint i, uint j, uint element, uint stride) { coopMatLoadNV(fc[i * FN + j], m, element, stride, false); }
void store_c(uint i, uint j, uint element, uint stride) { coopMatStoreNV(fc[i * FN + j], m, element, stride, false); }
void mul_add(uint i, uint j) { fc[i * FN + j] = coopMatMulAddNV(fa[i], fb[j], fc[i * FN + j]); }
#endif

void main() {
  // Every invocation runs the same loops (no early exit): fragment ops and barriers stay uniform.
  const uint co0 = gl_WorkGroupID.y * FM * lM, t0 = (gl_WorkGroupID.x * NW + warp_id()) * FN * lN;
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) {
      if (ACCUM != 0u)
        load_c(i, j, (co0 + i * lM) * p.pix_pad + t0 + j * lN, p.pix_pad);
      else
        zero_c(i, j);
    }
  for (uint k = 0; k < p.chunk_pad; k += lK) {
    for (uint i = 0; i < FM; ++i) load_a(i, (co0 + i * lM) * p.cin_pad + p.c_begin + k, p.cin_pad);
    for (uint j = 0; j < FN; ++j) load_b(j, k * p.pix_pad + t0 + j * lN, p.pix_pad);
    sync();  // emulated: the fragments are complete before any invocation reads them
    for (uint i = 0; i < FM; ++i)
      for (uint j = 0; j < FN; ++j) mul_add(i, j);
    sync();  // emulated: read before the next step overwrites them
  }
  for (uint i = 0; i < FM; ++i)
    for (uint j = 0; j < FN; ++j) store_c(i, j, (co0 + i * lM) * p.pix_pad + t0 + j * lN, p.pix_pad);
}
