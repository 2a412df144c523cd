#version 450
// In place: integer event counts -> float32 (exact below 2^24 per cell).
layout(local_size_x = 256) in;
layout(std430, binding = 0) buffer Counts { uint v[]; };
layout(push_constant) uniform P { uint n; } p;
void main() {
  const uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  for (uint i = gl_GlobalInvocationID.x; i < p.n; i += stride) v[i] = floatBitsToUint(float(v[i]));
}
