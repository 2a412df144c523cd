// The body of winograd45_output.comp / winograd63_output.comp (M in a storage buffer) and their _texel
// forms (M through an RGBA32F uniform texel buffer, WINOGRAD_TEXEL_M; the .comp includes
// precision.glsl first). Step 3 of Winograd on 8x8 tiles, F(4x4, 5x5) (TILE_OUT 4) or F(6x6, 3x3)
// (TILE_OUT 6): Y = A^T M A of the 64 positions for four horizontally adjacent tiles of one output
// channel per invocation, then bias, the fused activation and the optional residual, written into
// the output slice (edges masked). As winograd_output.glsl, with 8x8 tiles.
#ifndef TILE_OUT
#define TILE_OUT 4
#endif
const uint TO = TILE_OUT;
#include "winograd_output_io.glsl"

// A^T x for 8 values (4 tiles side by side): the TILE_OUT outputs (row i: the points to the power i).
void at8(vec4 m0, vec4 m1, vec4 m2, vec4 m3, vec4 m4, vec4 m5, vec4 m6, vec4 m7, out vec4 o[TILE_OUT]) {
  vec4 sp = m1 + m2, sm = m1 - m2, tp = m3 + m4, tm = m3 - m4, hp = m5 + m6, hm = m5 - m6;
#if TILE_OUT == 4
  o[0] = m0 + sp + tp + hp;
  o[1] = sm + 2.0 * tm + 0.5 * hm;
  o[2] = sp + 4.0 * tp + 0.25 * hp;
  o[3] = sm + 8.0 * tm + 0.125 * hm + m7;
#else
  o[0] = m0 + sp + tp + hp;
  o[1] = sm + 2.0 * tm + 0.5 * hm;
  o[2] = sp + 4.0 * tp + 0.25 * hp;
  o[3] = sm + 8.0 * tm + 0.125 * hm;
  o[4] = sp + 16.0 * tp + 0.0625 * hp;
  o[5] = sm + 32.0 * tm + 0.03125 * hm + m7;
#endif
}

void main() {
  uint gi = gl_GlobalInvocationID.x, co = gl_GlobalInvocationID.y;
  if (gi >= p.ngroups) return;
  uint gx = p.tiles_x_pad / 4u;
  uint row = gi / gx, n = row / p.tiles_y, ty = row % p.tiles_y;
  uint oy0 = ty * TO, ox0 = (gi % gx) * 4u * TO;
  uint stride = p.cout_pad * p.tiles_pad / 4u, b = co * p.tiles_pad / 4u + gi;
  vec4 t4[TILE_OUT][8];  // A^T M
  [[unroll]] for (uint j = 0; j < 8u; ++j) {
    vec4 o[TILE_OUT];
    at8(load_m(b + j * stride), load_m(b + (8u + j) * stride), load_m(b + (16u + j) * stride), load_m(b + (24u + j) * stride),
        load_m(b + (32u + j) * stride), load_m(b + (40u + j) * stride), load_m(b + (48u + j) * stride),
        load_m(b + (56u + j) * stride), o);
    [[unroll]] for (uint i = 0; i < TO; ++i) t4[i][j] = o[i];
  }
  float bv = bias[co];
  uint ob = p.out_off + n * p.out_bs + co * p.oh * p.ow, rb = p.res_off + n * p.res_bs + co * p.oh * p.ow;
  [[unroll]] for (uint i = 0; i < TO; ++i) {
    vec4 o4[TILE_OUT];
    at8(t4[i][0], t4[i][1], t4[i][2], t4[i][3], t4[i][4], t4[i][5], t4[i][6], t4[i][7], o4);
    if (oy0 + i >= p.oh) continue;  // a whole row past the bottom edge
    [[unroll]] for (uint t = 0; t < 4u; ++t)  // tile within the group
      [[unroll]] for (uint j = 0; j < TO; ++j)  // column within the tile
        store_output(ob, rb, oy0 + i, ox0 + t * TO + j, o4[j][t] + bv);
  }
}
