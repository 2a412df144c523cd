// The input of the direct convs (conv2d_direct.glsl, conv_transpose2d_direct.glsl) at binding 0:
// through a uniform texel buffer (an R32 view, R16 in the fp16 variant) with DIRECT_TEXEL_INPUT,
// which llvmpipe fetches with a gather where a storage-buffer load is a per-lane loop (1.2-1.5x
// faster on lavapipe); else a storage buffer (the fallback for inputs beyond maxTexelBufferElements).
// Also the weights: a uniform slab of SLAB 16-byte entries, vec4s (fp32) or uvec4s holding 8 halves
// (fp16: no 16-bit uniform-buffer feature needed; unpackHalf2x16 is core GLSL).
#ifdef DIRECT_TEXEL_INPUT
layout(binding = 0) uniform samplerBuffer xin;
float load_input(uint i) { return texelFetch(xin, int(i)).r; }
#else
layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
float load_input(uint i) { return float(x[i]); }
#endif
#ifdef VKU_FP16
layout(std140, binding = 1) uniform Wt { uvec4 wt[SLAB]; };
vec4 weight4(uint i) {
  uvec4 u = wt[i >> 1u];
  uvec2 h = (i & 1u) == 0u ? u.xy : u.zw;
  return vec4(unpackHalf2x16(h.x), unpackHalf2x16(h.y));
}
#else
layout(std140, binding = 1) uniform Wt { vec4 wt[SLAB]; };
vec4 weight4(uint i) { return wt[i]; }
#endif
