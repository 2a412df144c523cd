#version 450
// EDI physics unroller: log I(t*) = log I_rs + log T - LSE_j(log len_j + c E_j); see
// kernels/physics_unroll.hpp for the formula. Two passes (PASS, a specialization constant, so that
// each pipeline holds only its own code: lavapipe runs both sides of a branch under a mask):
//   0, every pixel: no event means the ratio 1, and the formula then reduces to clamp(v, 0, keep_max)
//      with keep_max = (max_value - log_offset)^(1/gamma), without transcendentals or their rounding;
//   1, the listed pixels (those with events): the formula, overwriting pass 0's value.
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint PASS = 1;
layout(std430, binding = 0) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 1) readonly buffer Tau { float tau[]; };
layout(std430, binding = 2) readonly buffer Pol { int pol[]; };
layout(std430, binding = 3) readonly buffer Rows { float rows[]; };  // [start_y..., end_y...]
layout(std430, binding = 4) readonly buffer Rs { float rs[]; };
layout(std430, binding = 5) writeonly buffer Out { float result[]; };
layout(std430, binding = 6) readonly buffer Listed { uint listed[]; };  // pass 1: pixel indices
layout(push_constant) uniform P {
  int width, height, channels;
  float contrast, gamma, max_value, log_offset, keep_max;
  uint rs_off, out_off;  // element offsets of the image and of the output item (a batch's item)
  uint count;  // invocations (pass 0: a quarter of the pixels; pass 1: the listed pixels)
} p;

void main() {
  const uint k = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 64u + gl_GlobalInvocationID.x;  // flat_groups
  if (k >= p.count) return;
  const int plane = p.width * p.height;
  if (PASS == 0) {  // four pixels an invocation: llvmpipe's per-invocation cost outweighs one copy
    const uint first = 4u * k, last = min(first + 4u, uint(plane));
    for (int c = 0; c < p.channels; ++c)
      for (uint q = first; q < last; ++q)
        result[p.out_off + c * plane + q] = clamp(rs[p.rs_off + c * plane + q], 0.0, p.keep_max);
    return;
  }
  const int pix = int(listed[k]), y = pix / p.width;
  const uint b = offsets[pix], e = offsets[pix + 1];
  const float S = rows[y], E = rows[p.height + y];
  const float T = E - S;
  // F0: polarity sum up to t* (tau <= 0); F at S: sum up to S (right-continuous).
  int f0 = 0, fs = 0;
  for (uint i = b; i < e; ++i) {
    if (tau[i] <= 0.0) f0 += pol[i];
    if (tau[i] <= S) fs += pol[i];
  }
  float log_ratio = 0.0;  // log(T / integral); 0 when the exposure is empty
  if (T > 0.0) {
    float m = -1e30, acc = 0.0, prev = S;
    int f = fs;
    for (uint i = b; i <= e; ++i) {
      const bool last = (i == e);
      const float t = last ? E : tau[i];
      if (!last && t <= S) continue;
      const float seg_end = min(t, E);
      if (seg_end > prev) {
        const float v = log(seg_end - prev) + p.contrast * float(f - f0);
        if (v > m) { acc = acc * exp(m - v) + 1.0; m = v; } else { acc += exp(v - m); }
        prev = seg_end;
      }
      if (last || t >= E) break;
      f += pol[i];
    }
    log_ratio = log(T) - (m + log(acc));
  }
  for (int c = 0; c < p.channels; ++c) {
    const float v = rs[p.rs_off + c * plane + pix];
    // Events measure log(lin + log_offset): the ratio applies to the offset intensity.
    float lin = (v > 0.0 ? pow(v, p.gamma) : 0.0) + p.log_offset;
    // Cap the exponent, not exp's result: log_ratio can be ~c * millions of events, and exp of
    // that overflows (inf, or whatever a fast exp returns there); log(0) is never taken (lin > 0).
    float o = lin > 0.0 ? min(exp(min(log(lin) + log_ratio, log(p.max_value))), p.max_value) - p.log_offset : 0.0;
    result[p.out_off + c * plane + pix] = o > 0.0 ? pow(o, 1.0 / p.gamma) : 0.0;
  }
}
