#version 450
// A workgroup of WG invocations (constant 0) and 2 * N floats of shared memory (constant 1): what the
// pipelines' limit check reads from a module once its specialization constants are applied.
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint N = 1024;
layout(std430, binding = 0) buffer Y { float y[]; };
shared float s[2u * N];
void main() {
  const uint i = gl_LocalInvocationID.x;
  s[i % (2u * N)] = float(i);
  barrier();
  y[gl_GlobalInvocationID.x] = s[(i + 1u) % (2u * N)];
}
