#version 450
#extension GL_GOOGLE_include_directive : require
// conv2d with register blocking: each invocation computes PX (8) consecutive output pixels of one row
// for COB (8 or 16) output channels (PX x COB accumulators). Per input channel and kernel row it
// loads the PX*STRIDE + K - STRIDE input values once and reuses them for all K taps and COB
// channels; the weights are packed [cout/COB][cin][K][K][COB] so the COB channels of one tap are
// COB/4 vec4 loads, the same for the whole workgroup.
// Invocations are numbered over (output row, block of PX columns), so small and narrow images keep
// every lane busy.
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
layout(constant_id = 0) const uint K = 3;
layout(constant_id = 1) const uint STRIDE = 1;
layout(constant_id = 2) const uint ACT = 0;
layout(constant_id = 3) const float SLOPE = 0.0;
layout(constant_id = 4) const uint HAS_RES = 0;
layout(constant_id = 5) const uint PX = 8;
layout(constant_id = 6) const uint CQ = 2;  // vec4s of output channels per invocation (COB / 4)
const uint COB = CQ * 4u;
#include "act.glsl"
#include "precision.glsl"

const uint ROW = PX * STRIDE + K - STRIDE;  // input values one kernel row of PX outputs touches

layout(std430, binding = 0) readonly buffer In { SFLOAT x[]; };
layout(std430, binding = 1) readonly buffer Wt { SVEC4 wt[]; };
layout(std430, binding = 2) readonly buffer Bias { vec4 bias[]; };
layout(std430, binding = 3) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = 4) writeonly buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad;
} p;

void main() {
  uint cob_count = (p.cout + COB - 1u) / COB;
  uint n = gl_WorkGroupID.z / cob_count, cob = gl_WorkGroupID.z % cob_count;
  uint xblocks = (p.ow + PX - 1u) / PX;
  uint blk = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;
  uint ox0 = (blk % xblocks) * PX, oy = blk / xblocks;
  // No early return and no branch on the invocation's position before the main loop: out-of-range
  // invocations compute clamped garbage that is never stored (divergent control flow costs more).
  bool live = ox0 < p.ow && oy < p.oh;
  int iy0 = int(oy * STRIDE) - int(p.pad), ix0 = int(ox0 * STRIDE) - int(p.pad);

  vec4 acc[PX][CQ];
  for (uint q = 0; q < CQ; ++q) {
    vec4 b0 = bias[cob * CQ + q];
    for (uint j = 0; j < PX; ++j) acc[j][q] = b0;
  }

  bool colok[ROW];
  for (uint i = 0; i < ROW; ++i) colok[i] = ix0 + int(i) >= 0 && ix0 + int(i) < int(p.w);
  uint plane = p.h * p.w;
  uint ib = p.in_off + n * p.in_bs;
  uint wb = cob * p.cin * K * K * CQ;
  for (uint ci = 0; ci < p.cin; ++ci, ib += plane, wb += K * K * CQ) {
    for (uint ky = 0; ky < K; ++ky) {
      int iy = iy0 + int(ky);
      bool rowok = iy >= 0 && iy < int(p.h);
      float row[ROW];
      uint rb = ib + uint(clamp(iy, 0, int(p.h) - 1)) * p.w;
      for (uint i = 0; i < ROW; ++i) {
        float v = float(x[rb + uint(clamp(ix0 + int(i), 0, int(p.w) - 1))]);
        row[i] = (rowok && colok[i]) ? v : 0.0;
      }
      for (uint kx = 0; kx < K; ++kx) {
        uint wi = wb + (ky * K + kx) * CQ;
        for (uint q = 0; q < CQ; ++q) {
          vec4 wq = vec4(wt[wi + q]);
          for (uint j = 0; j < PX; ++j) acc[j][q] += row[j * STRIDE + kx] * wq;
        }
      }
    }
  }

  if (!live) return;
  uint ob = p.out_off + n * p.out_bs;
  uint rbase = p.res_off + n * p.res_bs;
  uint oplane = p.oh * p.ow;
  for (uint h = 0; h < CQ; ++h)
    for (uint c = 0; c < 4u; ++c) {
      uint co = cob * COB + h * 4u + c;
      if (co >= p.cout) continue;
      for (uint j = 0; j < PX; ++j) {
        uint ox = ox0 + j;
        if (ox >= p.ow) continue;
        uint o = co * oplane + oy * p.ow + ox;
        float v = act(acc[j][h][c]);
        if (HAS_RES != 0u) v += float(res[rbase + o]);
        y[ob + o] = to_s(v);
      }
    }
}
