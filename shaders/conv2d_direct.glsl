// conv2d, register-blocked direct algorithm with the weights in a uniform buffer: each invocation
// computes PX consecutive output pixels in each of PY rows (lanes = pixels) for COB = 4 CQ output
// channels. Per input channel and input row it loads the PX*STRIDE + K - STRIDE input values once and
// reuses them for all taps, output rows and COB channels that read them. On lavapipe a uniform-buffer load is a straight-line gather
// while a storage-buffer load in a loop is a per-lane loop, so the weights (the same for every lane)
// come from a uniform block: the slab [chunk][K][K][CQ] vec4 of one block of COB output channels.
// The body of conv2d_direct.comp (input in a storage buffer) and conv2d_direct_texel.comp (input
// through a uniform texel buffer, DIRECT_TEXEL_INPUT).
// One dispatch = one channel block x one chunk of input channels (the slab must fit
// maxUniformBufferRange); chunks after the first add to the raw sums already in the output, the
// last applies the activation and the residual. A 1x1 stride-1 conv runs as one row of H*W pixels.
layout(local_size_x = 16) in;
layout(constant_id = 0) const uint K = 3;
layout(constant_id = 1) const uint STRIDE = 1;
layout(constant_id = 2) const uint ACT = 0;
layout(constant_id = 3) const float SLOPE = 0.0;
layout(constant_id = 4) const uint HAS_RES = 0;
layout(constant_id = 5) const uint PX = 8;
layout(constant_id = 6) const uint CQ = 4;       // vec4s of output channels per invocation
layout(constant_id = 7) const uint FIRST = 1;    // first input-channel chunk: start from the bias
layout(constant_id = 8) const uint LAST = 1;     // last chunk: activation and residual
layout(constant_id = 9) const uint SLAB = 4096;  // 16-byte entries of the bound weight slab
layout(constant_id = 10) const uint PY = 1;      // output rows per invocation
layout(constant_id = 11) const uint NC = 4;      // output channels computed when CQ == 1 (1-4): the heads
#include "act.glsl"
#include "precision.glsl"

const uint ROW = PX * STRIDE + K - STRIDE;  // input values one kernel row of PX outputs touches
const uint ROWS = PY * STRIDE + K - STRIDE;  // input rows PY output rows touch
// Components of each vec4 that carry a real output channel: a 1-channel head (attfusion_net.pred)
// skips the 3 padding channels' multiply-adds, which cost as much as its input fetches on lavapipe.
const uint NCV = CQ == 1u ? NC : 4u;

#include "direct_input.glsl"
layout(std430, binding = 2) readonly buffer Bias { float bias[]; };
layout(std430, binding = 3) readonly buffer Res { SFLOAT res[]; };
layout(std430, binding = 4) buffer Out { SFLOAT y[]; };
layout(push_constant) uniform P {
  uint in_off, in_bs, res_off, res_bs, out_off, out_bs;
  uint cin, h, w, cout, oh, ow, pad, co0;  // cin: input channels of this chunk; co0: first output channel
} p;

void main() {
  uint n = gl_WorkGroupID.z;
  uint xblocks = (p.ow + PX - 1u) / PX;
  uint blk = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 16u + gl_GlobalInvocationID.x;
  uint ox0 = (blk % xblocks) * PX, oy0 = (blk / xblocks) * PY;
  // Out-of-range invocations compute clamped garbage that is never stored (no divergent loop).
  bool live = oy0 < p.oh;
  oy0 = min(oy0, p.oh - 1u);
  int iy0 = int(oy0 * STRIDE) - int(p.pad), ix0 = int(ox0 * STRIDE) - int(p.pad);
  uint ob = p.out_off + n * p.out_bs, oplane = p.oh * p.ow;

  vec4 acc[PY][PX][CQ];
  [[unroll]] for (uint q = 0; q < CQ; ++q)
    [[unroll]] for (uint c = 0; c < 4u; ++c) {
      if (c >= NCV) {  // padding channels: never stored
        [[unroll]] for (uint t = 0; t < PY; ++t)
          [[unroll]] for (uint j = 0; j < PX; ++j) acc[t][j][q][c] = 0.0;
        continue;
      }
      uint co = min(p.co0 + q * 4u + c, p.cout - 1u);
      [[unroll]] for (uint t = 0; t < PY; ++t) {
        uint oy = min(oy0 + t, p.oh - 1u);
        if (FIRST != 0u) {
          float b = bias[co];
          [[unroll]] for (uint j = 0; j < PX; ++j) acc[t][j][q][c] = b;
        } else {
          [[unroll]] for (uint j = 0; j < PX; ++j) acc[t][j][q][c] = float(y[ob + co * oplane + oy * p.ow + min(ox0 + j, p.ow - 1u)]);
        }
      }
    }

  bool colok[ROW];
  uint colc[ROW];
  [[unroll]] for (uint i = 0; i < ROW; ++i) {
    int ix = ix0 + int(i);
    colok[i] = ix >= 0 && ix < int(p.w);
    colc[i] = uint(clamp(ix, 0, int(p.w) - 1));
  }
  uint plane = p.h * p.w;
  uint ib = p.in_off + n * p.in_bs;
  uint wb = 0u;
  for (uint ci = 0; ci < p.cin; ++ci, ib += plane, wb += K * K * CQ) {
    [[unroll]] for (uint r = 0; r < ROWS; ++r) {
      int iy = iy0 + int(r);
      bool rowok = iy >= 0 && iy < int(p.h);
      uint rb = ib + uint(clamp(iy, 0, int(p.h) - 1)) * p.w;
      float row[ROW];
      [[unroll]] for (uint i = 0; i < ROW; ++i) {
        float v = load_input(rb + colc[i]);
        row[i] = (rowok && colok[i]) ? v : 0.0;
      }
      [[unroll]] for (uint t = 0; t < PY; ++t) {  // output row t reads input row r with kernel row r - t*STRIDE
        int ky = int(r) - int(t * STRIDE);
        if (ky < 0 || ky >= int(K)) continue;  // resolved at compile time (constant trip counts)
        [[unroll]] for (uint kx = 0; kx < K; ++kx) {
          uint wi = wb + (uint(ky) * K + kx) * CQ;
          [[unroll]] for (uint q = 0; q < CQ; ++q) {
            vec4 wq = weight4(wi + q);
            if (NCV == 4u) {
              [[unroll]] for (uint j = 0; j < PX; ++j) acc[t][j][q] += row[j * STRIDE + kx] * wq;
            } else {
              [[unroll]] for (uint c = 0; c < NCV; ++c)
                [[unroll]] for (uint j = 0; j < PX; ++j) acc[t][j][q][c] += row[j * STRIDE + kx] * wq[c];
            }
          }
        }
      }
    }
  }

  if (!live) return;
  uint rbase = p.res_off + n * p.res_bs;
  [[unroll]] for (uint t = 0; t < PY; ++t) {
    uint oy = oy0 + t;
    if (oy >= p.oh) continue;
    [[unroll]] for (uint q = 0; q < CQ; ++q)
      [[unroll]] for (uint c = 0; c < 4u; ++c) {
        uint co = p.co0 + q * 4u + c;
        if (c >= NCV || co >= p.cout) continue;
        [[unroll]] for (uint j = 0; j < PX; ++j) {
          uint ox = ox0 + j;
          if (ox >= p.ow) continue;
          uint o = co * oplane + oy * p.ow + ox;
          float v = acc[t][j][q][c];
          if (LAST != 0u) {
            v = act(v);
            if (HAS_RES != 0u) v += float(res[rbase + o]);
          }
          y[ob + o] = to_s(v);
        }
      }
  }
}
