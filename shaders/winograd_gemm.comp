#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Winograd's GEMM, V and U in storage buffers (see winograd_gemm.glsl). fp16 variant (the 1x1
// GEMM's: Winograd keeps U and V fp32 and runs the fp32 one): U and V as float16, M fp32.
#include "precision.glsl"
#include "winograd_gemm.glsl"
