// The body of winograd_output.comp (M in a storage buffer) and winograd_output_texel.comp (M through
// an RGBA32F uniform texel buffer, WINOGRAD_TEXEL_M; the .comp includes precision.glsl first).
// Winograd F(4x4, 3x3), step 3: Y = A^T M A for four horizontally adjacent tiles of one output
// channel per invocation (vec4 loads of M), then bias, the fused activation and the optional
// residual, written into the output slice (edges masked).
#include "winograd_output_io.glsl"

void main() {
  uint gi = gl_GlobalInvocationID.x, co = gl_GlobalInvocationID.y;
  if (gi >= p.ngroups) return;
  uint gx = p.tiles_x_pad / 4u;
  uint row = gi / gx, n = row / p.tiles_y, ty = row % p.tiles_y;
  uint oy0 = ty * 4u, ox0 = (gi % gx) * 16u;
  uint stride = p.cout_pad * p.tiles_pad / 4u, b = co * p.tiles_pad / 4u + gi;
  vec4 t4[4][6];  // A^T M
  [[unroll]] for (uint j = 0; j < 6u; ++j) {
    vec4 m0 = load_m(b + j * stride), m1 = load_m(b + (6u + j) * stride), m2 = load_m(b + (12u + j) * stride);
    vec4 m3 = load_m(b + (18u + j) * stride), m4 = load_m(b + (24u + j) * stride), m5 = load_m(b + (30u + j) * stride);
    t4[0][j] = m0 + m1 + m2 + m3 + m4;
    t4[1][j] = m1 - m2 + 2.0 * (m3 - m4);
    t4[2][j] = m1 + m2 + 4.0 * (m3 + m4);
    t4[3][j] = m1 - m2 + 8.0 * (m3 - m4) + m5;
  }
  float bv = bias[co];
  uint ob = p.out_off + n * p.out_bs + co * p.oh * p.ow, rb = p.res_off + n * p.res_bs + co * p.oh * p.ow;
  [[unroll]] for (uint i = 0; i < 4u; ++i) {
    vec4 r0 = t4[i][0], r1 = t4[i][1], r2 = t4[i][2], r3 = t4[i][3], r4 = t4[i][4], r5 = t4[i][5];
    vec4 o4[4];
    o4[0] = r0 + r1 + r2 + r3 + r4;
    o4[1] = r1 - r2 + 2.0 * (r3 - r4);
    o4[2] = r1 + r2 + 4.0 * (r3 + r4);
    o4[3] = r1 - r2 + 8.0 * (r3 - r4) + r5;
    if (oy0 + i >= p.oh) continue;  // a whole row past the bottom edge
    [[unroll]] for (uint t = 0; t < 4u; ++t)    // tile within the group
      [[unroll]] for (uint j = 0; j < 4u; ++j)  // column within the tile
        store_output(ob, rb, oy0 + i, ox0 + t * 4u + j, o4[j][t] + bv);
  }
}
