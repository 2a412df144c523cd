#version 450
// Puts the cells the previous sparse build counted back to zero (a cell may be listed more than
// once; writing zero twice is harmless), so the persistent output is all zeros again without a
// dense fill.
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Touched { uint touched[]; };
layout(std430, binding = 1) writeonly buffer Counts { uint counts[]; };
layout(push_constant) uniform P {
  uint n;  // entries in the list
} p;

void main() {
  const uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  for (uint i = gl_GlobalInvocationID.x; i < p.n; i += stride) counts[touched[i]] = 0u;
}
