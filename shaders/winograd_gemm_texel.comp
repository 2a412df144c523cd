#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Winograd's GEMM, V and U through uniform texel buffers (RGBA32F views; RGBA16F for the 1x1 GEMM's
// float16 operands: the fetch returns fp32 either way, so there is no fp16 variant): llvmpipe
// fetches a texel with a gather where a storage-buffer load is a per-lane loop (docs/kernels.md).
// See winograd_gemm.glsl.
#define WINOGRAD_GEMM_TEXEL
#include "winograd_gemm.glsl"
