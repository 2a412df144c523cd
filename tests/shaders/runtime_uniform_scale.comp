#version 450
// The runtime's uniform-buffer self-test: y[i] = x[i] * s[i % 16] with s read from a uniform block.
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer X { float x[]; };
layout(std140, binding = 1) uniform S { vec4 s[4]; };
layout(std430, binding = 2) writeonly buffer Y { float y[]; };
layout(push_constant) uniform P { uint n; } p;
void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i < p.n) y[i] = x[i] * s[(i % 16u) / 4u][i % 4u];
}
