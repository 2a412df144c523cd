// conv_transpose2d, kernel 4, stride 2, padding 1, by phase decomposition (as
// conv_transpose2d_blocked: an output pixel of row parity py and column parity px receives exactly
// 2x2 taps), with the weights in a uniform buffer (on lavapipe a straight-line gather, while a
// storage-buffer load in a loop is a per-lane loop): each invocation computes PX output pixels of
// one parity along a row for COB = 4 CQ output channels. One dispatch = one channel block x one
// chunk of input channels (slab [chunk][4][4][CQ] vec4 within maxUniformBufferRange); chunks after
// the first add to the raw sums in the output, the last applies the activation.
// The body of conv_transpose2d_direct.comp (input in a storage buffer) and
// conv_transpose2d_direct_texel.comp (through a uniform texel buffer, DIRECT_TEXEL_INPUT).
layout(local_size_x = 16) in;
layout(constant_id = 0) const uint ACT = 0;
layout(constant_id = 1) const float SLOPE = 0.0;
layout(constant_id = 2) const uint PX = 8;
layout(constant_id = 3) const uint CQ = 4;
layout(constant_id = 4) const uint FIRST = 1;
layout(constant_id = 5) const uint LAST = 1;
layout(constant_id = 6) const uint SLAB = 4096;  // 16-byte entries of the bound weight slab
#include "act.glsl"
#include "precision.glsl"

#include "direct_input.glsl"
layout(std430, binding = 2) readonly buffer Bias { float bias[]; };
layout(std430, binding = 3) buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad, co0;
} p;

void main() {
  uint n = gl_WorkGroupID.z;
  uint xblocks = ((p.ow + 1u) / 2u + PX - 1u) / PX;
  uint blk = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 16u + gl_GlobalInvocationID.x;
  uint rem = blk % (2u * xblocks), oy = blk / (2u * xblocks);
  uint px = rem % 2u, m0 = (rem / 2u) * PX;
  bool live = oy < p.oh;
  oy = min(oy, p.oh - 1u);
  uint py = oy % 2u, r = oy / 2u;
  uint ob = p.out_off + n * p.out_bs, oplane = p.oh * p.ow;

  vec4 acc[PX][CQ];
  [[unroll]] for (uint q = 0; q < CQ; ++q)
    [[unroll]] for (uint c = 0; c < 4u; ++c) {
      uint co = min(p.co0 + q * 4u + c, p.cout - 1u);
      if (FIRST != 0u) {
        float b = bias[co];
        [[unroll]] for (uint j = 0; j < PX; ++j) acc[j][q][c] = b;
      } else {
        [[unroll]] for (uint j = 0; j < PX; ++j)
          acc[j][q][c] = float(y[ob + co * oplane + oy * p.ow + min(2u * (m0 + j) + px, p.ow - 1u)]);
      }
    }
  int xbase = int(m0) - 1 + int(px);  // input column of local index 0
  bool colok[PX + 1u];
  uint colc[PX + 1u];
  [[unroll]] for (uint i = 0; i <= PX; ++i) {
    int ix = xbase + int(i);
    colok[i] = ix >= 0 && ix < int(p.w);
    colc[i] = uint(clamp(ix, 0, int(p.w) - 1));
  }
  uint plane = p.h * p.w;
  uint ib = p.in_off + n * p.in_bs;
  uint wb = 0u;
  for (uint ci = 0; ci < p.cin; ++ci, ib += plane, wb += 16u * CQ) {
    [[unroll]] for (uint t = 0; t < 2u; ++t) {  // t = 0: ky = 1-py, input row r+py; t = 1: ky = 3-py, row r-1+py
      int iy = int(r + py) - int(t);
      uint ky = 1u - py + 2u * t;
      bool rowok = iy >= 0 && iy < int(p.h);
      uint rb = ib + uint(clamp(iy, 0, int(p.h) - 1)) * p.w;
      float row[PX + 1u];
      [[unroll]] for (uint i = 0; i <= PX; ++i) {
        float v = load_input(rb + colc[i]);
        row[i] = (rowok && colok[i]) ? v : 0.0;
      }
      // kx = 1-px reads local index j+1, kx = 3-px reads index j.
      uint wa = wb + (ky * 4u + 1u - px) * CQ, wc = wb + (ky * 4u + 3u - px) * CQ;
      [[unroll]] for (uint q = 0; q < CQ; ++q) {
        vec4 w1 = weight4(wa + q), w3 = weight4(wc + q);
        [[unroll]] for (uint j = 0; j < PX; ++j) acc[j][q] += row[j + 1u] * w1 + row[j] * w3;
      }
    }
  }
  if (!live) return;
  [[unroll]] for (uint q = 0; q < CQ; ++q)
    [[unroll]] for (uint c = 0; c < 4u; ++c) {
      uint co = p.co0 + q * 4u + c;
      if (co >= p.cout) continue;
      [[unroll]] for (uint j = 0; j < PX; ++j) {
        uint ox = 2u * (m0 + j) + px;
        if (ox >= p.ow) continue;
        float v = acc[j][q][c];
        y[ob + co * oplane + oy * p.ow + ox] = to_s(LAST != 0u ? act(v) : v);
      }
    }
}
