#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// conv2d, pointwise algorithm, input in a storage buffer (see conv2d_pointwise.glsl).
#include "precision.glsl"
#include "conv2d_pointwise.glsl"
