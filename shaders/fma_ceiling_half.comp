#version 450
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#extension GL_EXT_shader_16bit_storage : require
// The device's fp16 FMA ceiling for the bench (needs shaderFloat16): fma_ceiling.comp with f16vec4
// chains (8 independent accumulators per invocation, an unrolled loop, one store at the end).
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint ITERS = 1024;
layout(std430, binding = 0) writeonly buffer Out { f16vec4 y[]; };
layout(push_constant) uniform P { float a, b; } p;
void main() {
  float16_t s = float16_t(float(gl_GlobalInvocationID.x & 255u) * 1e-3);
  f16vec4 m = f16vec4(float16_t(p.a)), c = f16vec4(float16_t(p.b));
  f16vec4 a0 = f16vec4(s), a1 = a0 + float16_t(1.0), a2 = a0 + float16_t(2.0), a3 = a0 + float16_t(3.0);
  f16vec4 a4 = a0 + float16_t(4.0), a5 = a0 + float16_t(5.0), a6 = a0 + float16_t(6.0), a7 = a0 + float16_t(7.0);
  for (uint i = 0; i < ITERS; i += 4u) {
    for (uint u = 0; u < 4u; ++u) {  // unrolled by the compiler: constant trip count
      a0 = fma(a0, m, c); a1 = fma(a1, m, c); a2 = fma(a2, m, c); a3 = fma(a3, m, c);
      a4 = fma(a4, m, c); a5 = fma(a5, m, c); a6 = fma(a6, m, c); a7 = fma(a7, m, c);
    }
  }
  y[gl_GlobalInvocationID.x] = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7;
}
