#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Winograd F(4x4, 5x5) output transform, M in a storage buffer (see winograd8_output.glsl).
#include "precision.glsl"
#include "winograd8_output.glsl"
