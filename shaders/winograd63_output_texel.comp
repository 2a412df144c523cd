#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Winograd F(6x6, 3x3) output transform, M through a uniform texel buffer (see winograd8_output.glsl).
#define WINOGRAD_TEXEL_M
#define TILE_OUT 6
#include "precision.glsl"
#include "winograd8_output.glsl"
