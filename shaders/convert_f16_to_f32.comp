#version 450
#extension GL_GOOGLE_include_directive : require
// f16 slice -> f32 slice (see convert.glsl).
#define IN_T float16_t
#define OUT_T float
#include "convert.glsl"
