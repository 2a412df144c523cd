#version 450
#extension GL_GOOGLE_include_directive : require
// f32 slice -> f16 slice (see convert.glsl).
#define IN_T float
#define OUT_T float16_t
#include "convert.glsl"
