#version 450
// The device's FMA ceiling for the bench: 8 independent vec4 accumulator chains per invocation,
// an unrolled loop of fused multiply-adds, one store at the end so nothing is optimized away.
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint ITERS = 1024;
layout(std430, binding = 0) writeonly buffer Out { vec4 y[]; };
layout(push_constant) uniform P { float a, b; } p;
void main() {
  float s = float(gl_GlobalInvocationID.x) * 1e-7;
  vec4 m = vec4(p.a), c = vec4(p.b);
  vec4 a0 = vec4(s), a1 = a0 + 1.0, a2 = a0 + 2.0, a3 = a0 + 3.0;
  vec4 a4 = a0 + 4.0, a5 = a0 + 5.0, a6 = a0 + 6.0, a7 = a0 + 7.0;
  for (uint i = 0; i < ITERS; i += 4u) {
    for (uint u = 0; u < 4u; ++u) {  // unrolled by the compiler: constant trip count
      a0 = fma(a0, m, c); a1 = fma(a1, m, c); a2 = fma(a2, m, c); a3 = fma(a3, m, c);
      a4 = fma(a4, m, c); a5 = fma(a5, m, c); a6 = fma(a6, m, c); a7 = fma(a7, m, c);
    }
  }
  y[gl_GlobalInvocationID.x] = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7;
}
