#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Elementwise ops on slices, inputs through uniform texel buffers (elementwise.glsl).
#define ELEMENTWISE_TEXEL_INPUT 1
#include "precision.glsl"
#include "elementwise.glsl"
