// copy between an f32 and an f16 slice (convert_f32_to_f16.comp, convert_f16_to_f32.comp): the
// model's fp32 inputs (event tensors, images) into fp16 activations and its fp16 results back.
// IN_T and OUT_T are the element types; f32 -> f16 saturates at +-65504 (NaN stays NaN).
#extension GL_EXT_shader_16bit_storage : require
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { IN_T x[]; };
layout(std430, binding = 1) writeonly buffer Out { OUT_T y[]; };
layout(push_constant) uniform P { uint in_off, in_bs, out_off, out_bs, c, plane; } p;
void main() {
  uint i = gl_GlobalInvocationID.x, c = gl_GlobalInvocationID.y, n = gl_GlobalInvocationID.z;
  if (i >= p.plane || c >= p.c) return;
  float v = float(x[p.in_off + n * p.in_bs + c * p.plane + i]);
  y[p.out_off + n * p.out_bs + c * p.plane + i] = OUT_T(isnan(v) ? v : clamp(v, -65504.0, 65504.0));
}
