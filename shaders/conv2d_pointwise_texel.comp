#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// conv2d, pointwise algorithm, input through a uniform texel buffer (see conv2d_pointwise.glsl).
#define DIRECT_TEXEL_INPUT 1
#include "precision.glsl"
#include "conv2d_pointwise.glsl"
