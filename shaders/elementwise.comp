#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// Elementwise ops on slices, inputs from storage buffers (elementwise.glsl).
#include "precision.glsl"
#include "elementwise.glsl"
