// Cooperative-matrix fragment ops of the coopmat conv (conv2d_igemm_coopmat), in two forms:
// cmake/Shaders.cmake compiles every .comp that includes this file as <stem> (real,
// GL_NV_cooperative_matrix: a warp is one subgroup, so the device's subgroup size must be WARP) and
// <stem>_emulated (-DVKU_COOPMAT_EMULATE: a warp is WARP consecutive invocations; the A and B
// fragments live in shared memory, C in registers (fixed elements per invocation), and each op is
// plain loads and fp32 FMAs of the fp16 operands). The includer declares the spec constants lM, lN,
// lK (fragment A lM x lK, B lK x lN, C lM x lN), FM, FN (fragments per warp), NW (warps per
// workgroup) and WARP.
// Every op takes the same arguments in both forms, is called in uniform control flow, and reads or
// writes row-major: element (r, c) at BUF[element + r*stride + c], element and stride counted in
// BUF's scalars (float16_t for A and B, float for C); the _U4 loads read a uvec4 array (8 halves a
// word, the first in the low bits of .x) with element and stride counted in uvec4s.
#ifndef VKU_COOPMAT_GLSL
#define VKU_COOPMAT_GLSL
#ifdef VKU_COOPMAT_EMULATE
shared float16_t cm_a[NW * FM * lM * lK];
shared float16_t cm_b[NW * FN * lK * lN];
const uint CM_CPER = (lM * lN) / WARP;  // C elements per invocation and fragment (lM*lN % WARP == 0)
float cm_c[FM * FN * CM_CPER];          // element e = lane + q*WARP of fragment (i, j): cm_c[(i*FN + j)*CM_CPER + q]
uint warp_id() { return gl_LocalInvocationIndex / WARP; }
uint cm_lane() { return gl_LocalInvocationIndex % WARP; }
// barrier() in a compute shader is OpControlBarrier with workgroup-memory semantics: it orders the
// shared fragments. memoryBarrierShared() would add a Device-scope barrier, which under the Vulkan
// memory model (coopmat) needs vulkanMemoryModelDeviceScope (validation failed on NVIDIA, 2026-12-04).
void cm_sync() { barrier(); }  // fragments complete (or read) before the next op
#define CM_HALF_U4(BUF, h_) unpackFloat2x16(BUF[(h_) / 8u][((h_) % 8u) / 2u])[(h_) % 2u]
#define CM_LOAD_A_U4(i, BUF, element, stride)                                               \
  {                                                                                         \
    uint base_ = (warp_id() * FM + (i)) * lM * lK;                                          \
    for (uint e_ = cm_lane(); e_ < lM * lK; e_ += WARP)                                     \
      cm_a[base_ + e_] = CM_HALF_U4(BUF, ((element) + (e_ / lK) * (stride)) * 8u + e_ % lK); \
  }
#define CM_LOAD_B_U4(j, BUF, element, stride)                                               \
  {                                                                                         \
    uint base_ = (warp_id() * FN + (j)) * lK * lN;                                          \
    for (uint e_ = cm_lane(); e_ < lK * lN; e_ += WARP)                                     \
      cm_b[base_ + e_] = CM_HALF_U4(BUF, ((element) + (e_ / lN) * (stride)) * 8u + e_ % lN); \
  }
void cm_zero_c(uint i, uint j) {
  for (uint q = 0; q < CM_CPER; ++q) cm_c[(i * FN + j) * CM_CPER + q] = 0.0;
}
#define CM_STORE_C(i, j, BUF, element, stride)                                              \
  for (uint q_ = 0; q_ < CM_CPER; ++q_) {                                                   \
    uint e_ = cm_lane() + q_ * WARP;                                                        \
    BUF[(element) + (e_ / lN) * (stride) + e_ % lN] = cm_c[((i) * FN + (j)) * CM_CPER + q_]; \
  }
void cm_mul_add(uint i, uint j) {  // C(i, j) += A(i) B(j)
  uint a = (warp_id() * FM + i) * lM * lK, b = (warp_id() * FN + j) * lK * lN;
  for (uint q = 0; q < CM_CPER; ++q) {
    uint e = cm_lane() + q * WARP, r = e / lN, c = e % lN;
    float acc = cm_c[(i * FN + j) * CM_CPER + q];
    for (uint k = 0; k < lK; ++k) acc = fma(float(cm_a[a + r * lK + k]), float(cm_b[b + k * lN + c]), acc);
    cm_c[(i * FN + j) * CM_CPER + q] = acc;
  }
}
#else
#extension GL_NV_cooperative_matrix : require
#extension GL_KHR_memory_scope_semantics : require
#extension GL_KHR_shader_subgroup_basic : require
fcoopmatNV<16, gl_ScopeSubgroup, lM, lK> cm_fa[FM];
fcoopmatNV<16, gl_ScopeSubgroup, lK, lN> cm_fb[FN];
fcoopmatNV<32, gl_ScopeSubgroup, lM, lN> cm_fc[FM * FN];
uint warp_id() { return gl_SubgroupID; }
uint cm_lane() { return gl_SubgroupInvocationID; }
void cm_sync() {}  // the fragments are the subgroup's registers
// colMajor = false: row-major, element (r, c) at BUF[element + r*stride + c] (GL_NV_cooperative_matrix).
#define CM_LOAD_A_U4(i, BUF, element, stride) coopMatLoadNV(cm_fa[i], BUF, element, stride, false)
#define CM_LOAD_B_U4(j, BUF, element, stride) coopMatLoadNV(cm_fb[j], BUF, element, stride, false)
#define CM_STORE_C(i, j, BUF, element, stride) coopMatStoreNV(cm_fc[(i) * FN + (j)], BUF, element, stride, false)
void cm_zero_c(uint i, uint j) { cm_fc[i * FN + j] = fcoopmatNV<32, gl_ScopeSubgroup, lM, lN>(0.0); }
void cm_mul_add(uint i, uint j) { cm_fc[i * FN + j] = coopMatMulAddNV(cm_fa[i], cm_fb[j], cm_fc[i * FN + j]); }
#endif
#endif
