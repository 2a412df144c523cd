#version 450
#extension GL_EXT_control_flow_attributes : require
#extension GL_GOOGLE_include_directive : require
// conv_transpose2d, direct algorithm, input in a storage buffer (see conv_transpose2d_direct.glsl).
#include "precision.glsl"
#include "conv_transpose2d_direct.glsl"
