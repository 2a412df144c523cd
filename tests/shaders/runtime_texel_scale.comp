#version 450
// The runtime's texel-buffer self-test: y[i] = x[i] + 2 * q[i] with x read through an R32 view,
// q through an RGBA32 view (texel i / 4, component i % 4) and y written through a storage texel buffer.
layout(local_size_x = 64) in;
layout(binding = 0) uniform samplerBuffer x;
layout(binding = 1) uniform samplerBuffer q;
layout(binding = 2, r32f) uniform writeonly imageBuffer y;
layout(push_constant) uniform P { uint n; } p;
void main() {
  int i = int(gl_GlobalInvocationID.x);
  if (i < int(p.n)) imageStore(y, i, vec4(texelFetch(x, i).r + 2.0 * texelFetch(q, i / 4)[i % 4]));
}
