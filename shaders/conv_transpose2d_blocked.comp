#version 450
#extension GL_GOOGLE_include_directive : require
// conv_transpose2d, kernel 4, stride 2, padding 1, by phase decomposition: an output pixel of row
// parity py and column parity px receives exactly 2x2 taps (ky in {1-py, 3-py}, kx in {1-px, 3-px})
// from input rows r+py, r-1+py and columns m+px, m-1+px (oy = 2r+py, ox = 2m+px). Each invocation
// computes 8 output pixels of one parity along a row for 8 output channels (64 accumulators);
// weights packed [cout/8][cin][4][4][8].
// Invocations are numbered over (output row, column block, column parity).
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
layout(constant_id = 0) const uint ACT = 0;
layout(constant_id = 1) const float SLOPE = 0.0;
#include "act.glsl"
#include "precision.glsl"
const uint PX = 8;

layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) readonly buffer Wt { SVEC4 wt[]; };
layout(std430, binding = 2) readonly buffer Bias { vec4 bias[]; };
layout(std430, binding = 3) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad;
} p;

void main() {
  uint cob_count = (p.cout + 7u) / 8u;
  uint n = gl_WorkGroupID.z / cob_count, cob = gl_WorkGroupID.z % cob_count;
  uint xblocks = ((p.ow + 1u) / 2u + PX - 1u) / PX;
  uint blk = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  uint rem = blk % (2u * xblocks), oy = blk / (2u * xblocks);
  uint px = rem % 2u, m0 = (rem / 2u) * PX;
  bool live = m0 < (p.ow + 1u - px) / 2u && oy < p.oh;
  oy = min(oy, p.oh - 1u);
  uint py = oy % 2u, r = oy / 2u;

  vec4 acc[PX][2];
  vec4 b0 = bias[cob * 2u], b1 = bias[cob * 2u + 1u];
  for (uint j = 0; j < PX; ++j) { acc[j][0] = b0; acc[j][1] = b1; }
  int xbase = int(m0) - 1 + int(px);  // input column of local index 0
  bool colok[PX + 1u];
  uint colc[PX + 1u];
  for (uint i = 0; i <= PX; ++i) {
    int ix = xbase + int(i);
    colok[i] = ix >= 0 && ix < int(p.w);
    colc[i] = uint(clamp(ix, 0, int(p.w) - 1));
  }
  uint plane = p.h * p.w;
  uint ib = p.in_off + n * p.in_bs;
  uint wb = cob * p.cin * 32u;
  for (uint ci = 0; ci < p.cin; ++ci, ib += plane, wb += 32u) {
    for (uint t = 0; t < 2u; ++t) {  // t = 0: ky = 1-py, input row r+py; t = 1: ky = 3-py, row r-1+py
      int iy = int(r + py) - int(t);
      uint ky = 1u - py + 2u * t;
      bool rowok = iy >= 0 && iy < int(p.h);
      uint rb = ib + uint(clamp(iy, 0, int(p.h) - 1)) * p.w;
      float row[PX + 1u];
      for (uint i = 0; i <= PX; ++i) {
        float v = float(x[rb + colc[i]]);
        row[i] = (rowok && colok[i]) ? v : 0.0;
      }
      // kx = 1-px reads local index j+1, kx = 3-px reads index j.
      uint wa = wb + (ky * 4u + 1u - px) * 2u, wbb = wb + (ky * 4u + 3u - px) * 2u;
      vec4 wa0 = vec4(wt[wa]), wa1 = vec4(wt[wa + 1u]), wb0 = vec4(wt[wbb]), wb1 = vec4(wt[wbb + 1u]);
      for (uint j = 0; j < PX; ++j) {
        float va = row[j + 1u], vb = row[j];
        acc[j][0] += va * wa0 + vb * wb0;
        acc[j][1] += va * wa1 + vb * wb1;
      }
    }
  }
  if (!live) return;
  uint ob = p.out_off + n * p.out_bs, oplane = p.oh * p.ow;
  for (uint hh = 0; hh < 2u; ++hh)
    for (uint c = 0; c < 4u; ++c) {
      uint co = cob * 8u + hh * 4u + c;
      if (co >= p.cout) continue;
      for (uint j = 0; j < PX; ++j) {
        uint ox = 2u * (m0 + j) + px;
        if (ox >= p.ow) continue;
        y[ob + co * oplane + oy * p.ow + ox] = to_s(act(acc[j][hh][c]));
      }
    }
}
