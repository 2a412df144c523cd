#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Winograd F(4x4, 5x5) input transform, input through a uniform texel buffer (see winograd8_input.glsl).
#define WINOGRAD_TEXEL_INPUT
#include "precision.glsl"
#include "winograd8_input.glsl"
