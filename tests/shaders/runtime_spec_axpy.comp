#version 450
// The runtime's pipeline-compiler test op: y[i] = (a + B) * x[i] + y[i], B a specialization
// constant, so that each B is a pipeline of its own.
layout(local_size_x = 64) in;
layout(constant_id = 0) const float B = 0.0;
layout(std430, binding = 0) readonly buffer X { float x[]; };
layout(std430, binding = 1) buffer Y { float y[]; };
layout(push_constant) uniform P { float a; uint n; } p;
void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i < p.n) y[i] = (p.a + B) * x[i] + y[i];
}
