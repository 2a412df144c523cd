#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
// conv2d for 8-wide subgroups (lavapipe): the 8 lanes of a subgroup are 8 output channels (G
// groups of them per lane) of the same 8 output pixels. Each lane loads a different input pixel
// (4 input channels at once) and subgroupBroadcast hands every value to all lanes, so one load
// feeds 8 lanes x G channel groups x K taps; each lane's weights are vec4 over 4 input channels,
// packed [cout/(8G)][cin/4][K*K][G][8] (zero-padded). Register blocking: 8 x G accumulators.
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint K = 3;
layout(constant_id = 1) const uint STRIDE = 1;
layout(constant_id = 2) const uint ACT = 0;
layout(constant_id = 3) const float SLOPE = 0.0;
layout(constant_id = 4) const uint HAS_RES = 0;
layout(constant_id = 5) const uint G = 2;
#include "act.glsl"

const uint PX = 8;                             // output pixels per subgroup (one per lane when loading)
const uint ROW = PX * STRIDE + K - STRIDE;     // input columns those pixels touch in one kernel row
const uint NLOAD = (ROW + 7u) / 8u;            // loads of 8 lanes that cover them

layout(std430, binding = 0) readonly buffer In { float x[]; };
layout(std430, binding = 1) readonly buffer Wt { vec4 wt[]; };
layout(std430, binding = 2) readonly buffer Bias { float bias[]; };
layout(std430, binding = 3) readonly buffer Res { float res[]; };
layout(std430, binding = 4) writeonly buffer Out { float y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad;
} p;

#define BC(i) if ((i) < ROW) b[i] = subgroupBroadcast(v[(i) / 8], (i) % 8);

void main() {
  uint lane = gl_SubgroupInvocationID;
  uint task = gl_WorkGroupID.x * gl_NumSubgroups + gl_SubgroupID;
  uint xblocks = (p.ow + PX - 1u) / PX;
  uint oy = task / xblocks, ox0 = (task % xblocks) * PX;
  bool live = oy < p.oh;
  oy = min(oy, p.oh - 1u);
  uint cogs = (p.cout + 8u * G - 1u) / (8u * G);
  uint n = gl_WorkGroupID.z / cogs, cog = gl_WorkGroupID.z % cogs;

  float acc[PX][G];
  for (uint g = 0; g < G; ++g) {
    float b0 = bias[(cog * G + g) * 8u + lane];
    for (uint j = 0; j < PX; ++j) acc[j][g] = b0;
  }
  int iy0 = int(oy * STRIDE) - int(p.pad), ix0 = int(ox0 * STRIDE) - int(p.pad);
  uint lx[3];
  bool lok[3];
  for (uint l = 0; l < 3u; ++l) {
    int ix = ix0 + int(l * 8u + lane);
    lok[l] = ix >= 0 && ix < int(p.w);
    lx[l] = uint(clamp(ix, 0, int(p.w) - 1));
  }
  uint plane = p.h * p.w;
  uint ib = p.in_off + n * p.in_bs;
  uint c4n = (p.cin + 3u) / 4u;
  uint wbase = cog * c4n * K * K * G * 8u + lane;
  for (uint c4 = 0; c4 < c4n; ++c4) {
    for (uint ky = 0; ky < K; ++ky) {
      int iy = iy0 + int(ky);
      bool rowok = iy >= 0 && iy < int(p.h);
      uint rb = uint(clamp(iy, 0, int(p.h) - 1)) * p.w;
      vec4 v[3];
      for (uint l = 0; l < NLOAD; ++l)
        for (uint q = 0; q < 4u; ++q) {
          uint ch = c4 * 4u + q;
          float val = x[ib + min(ch, p.cin - 1u) * plane + rb + lx[l]];
          v[l][q] = (rowok && lok[l] && ch < p.cin) ? val : 0.0;
        }
      vec4 b[24];
      BC(0) BC(1) BC(2) BC(3) BC(4) BC(5) BC(6) BC(7) BC(8) BC(9) BC(10) BC(11)
      BC(12) BC(13) BC(14) BC(15) BC(16) BC(17) BC(18) BC(19) BC(20) BC(21) BC(22) BC(23)
      for (uint kx = 0; kx < K; ++kx)
        for (uint g = 0; g < G; ++g) {
          vec4 wv = wt[wbase + ((c4 * K * K + ky * K + kx) * G + g) * 8u];
          for (uint j = 0; j < PX; ++j) {
            vec4 bb = b[j * STRIDE + kx];
            acc[j][g] = fma(bb.x, wv.x, fma(bb.y, wv.y, fma(bb.z, wv.z, fma(bb.w, wv.w, acc[j][g]))));
          }
        }
    }
  }

  if (!live) return;
  uint ob = p.out_off + n * p.out_bs, rbase = p.res_off + n * p.res_bs, oplane = p.oh * p.ow;
  for (uint g = 0; g < G; ++g) {
    uint co = (cog * G + g) * 8u + lane;
    if (co >= p.cout) continue;
    for (uint j = 0; j < PX; ++j) {
      uint ox = ox0 + j;
      if (ox >= p.ow) continue;
      uint o = co * oplane + oy * p.ow + ox;
      float r = act(acc[j][g]);
      if (HAS_RES != 0u) r += res[rbase + o];
      y[ob + o] = r;
    }
  }
}
