// The input of the direct convs (conv2d_direct.glsl, conv_transpose2d_direct.glsl) at binding 0:
// through a uniform texel buffer (an R32 view) with DIRECT_TEXEL_INPUT, which llvmpipe fetches with
// a gather where a storage-buffer load is a per-lane loop (1.2-1.5x faster on lavapipe); else a
// storage buffer (the fallback for inputs beyond maxTexelBufferElements).
#ifdef DIRECT_TEXEL_INPUT
layout(binding = 0) uniform samplerBuffer xin;
float load_input(uint i) { return texelFetch(xin, int(i)).r; }
#else
layout(std430, binding = 0) readonly buffer In { float x[]; };
float load_input(uint i) { return x[i]; }
#endif
