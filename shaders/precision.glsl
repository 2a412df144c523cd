// Storage types of a shader's fp32 and fp16 variants. cmake/Shaders.cmake compiles every .comp that
// includes this file twice: <name> (fp32) and <name>_fp16 (-DVKU_FP16): activations, weights and
// scratch as float16_t in storage buffers, arithmetic in fp32 (the loads convert), so the fp16
// variant needs the storageBuffer16BitAccess feature only. Biases stay fp32 in both.
#ifndef VKU_PRECISION_GLSL
#define VKU_PRECISION_GLSL
#ifdef VKU_FP16
#extension GL_EXT_shader_16bit_storage : require
#define SFLOAT float16_t
#define SVEC4 f16vec4
// fp16 stores saturate at the largest finite half (65504): a value fp32 holds never becomes Inf
// (a NaN stays NaN).
SFLOAT to_s(float v) { return SFLOAT(isnan(v) ? v : clamp(v, -65504.0, 65504.0)); }
SVEC4 to_s4(vec4 v) { return SVEC4(mix(clamp(v, vec4(-65504.0), vec4(65504.0)), v, isnan(v))); }
#else
#define SFLOAT float
#define SVEC4 vec4
float to_s(float v) { return v; }
vec4 to_s4(vec4 v) { return v; }
#endif
#endif
