#version 450
#extension GL_EXT_control_flow_attributes : require
#extension GL_GOOGLE_include_directive : require
// conv_transpose2d, direct algorithm, input through a uniform texel buffer (see conv_transpose2d_direct.glsl).
#define DIRECT_TEXEL_INPUT 1
#include "precision.glsl"
#include "conv_transpose2d_direct.glsl"
