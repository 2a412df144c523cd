#version 450
// Row-aware event binning (reference section 4), one invocation per pixel: the host grouped the
// batch's events by pixel (counting sort), so each invocation owns its output cells, counts in
// registers and writes every channel once as float: no zero fill, no atomics, no conversion pass.
// Exact: the host turned the rational row times into integer thresholds (kernels/event_tensor.cpp).
// Record of (job, row), BINS + 4 ints: [lo, hi, BINS-1 ascending thresholds, flags (bit0: a > b), s, c].
// The host bounds jobs per dispatch so that jobs x (the pixel's events + 4N) stays under
// lavapipe's 65535 loop iterations per invocation (kernels/event_tensor.cpp, kLoopBudget).
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint BINS = 16;
layout(std430, binding = 0) readonly buffer Offsets { uint off[]; };  // [h*w + 1] first event of each pixel
layout(std430, binding = 1) readonly buffer Events { uint ev[]; };    // (t - origin) | positive << 31
layout(std430, binding = 2) readonly buffer Records { int rec[]; };
layout(std430, binding = 3) writeonly buffer Out { float o[]; };     // [jobs, 2*BINS, h, w]
layout(push_constant) uniform P {
  uint jobs;       // jobs in this chunk
  uint job_begin;  // first job of the chunk in the record table
  uint width, height;
  uint out_job;    // index of job_begin's job in the output chunk (a dispatch takes a few jobs)
} p;

void main() {
  const uint plane = p.width * p.height;
  const uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  for (uint pix = gl_GlobalInvocationID.x; pix < plane; pix += stride) {
    const uint y = pix / p.width;
    const uint e0 = off[pix], e1 = off[pix + 1u];
    for (uint j = 0u; j < p.jobs; ++j) {
      const uint base = ((p.job_begin + j) * p.height + y) * (BINS + 4u);
      const int lo = rec[base], hi = rec[base + 1u];
      const bool backward = (rec[base + BINS + 1u] & 1) != 0;
      const float sc = uintBitsToFloat(uint(rec[base + BINS + 2u]));
      const float c0 = uintBitsToFloat(uint(rec[base + BINS + 3u]));
      uint c[2u * BINS];
      for (uint k = 0u; k < 2u * BINS; ++k) c[k] = 0u;
      for (uint e = e0; e < e1; ++e) {
        const uint w = ev[e];
        const int t = int(w & 0x7fffffffu);
        if (t < lo || t >= hi) continue;  // half-open, empty when lo == hi
        // Threshold count j = #{thresholds <= t}: a float estimate, then exact integer steps.
        int jt = clamp(int(floor(float(t - lo) * sc + c0)), 0, int(BINS) - 1);
        for (int r = 0; r < 2; ++r) if (jt < int(BINS) - 1 && rec[base + 2u + uint(jt)] <= t) ++jt;
        for (int r = 0; r < 2; ++r) if (jt > 0 && rec[base + 1u + uint(jt)] > t) --jt;
        const uint first = uint(jt);
        const bool positive = (w >> 31) != 0u;
        const uint k = backward ? BINS - 1u - first : first;
        const bool s = backward ? !positive : positive;  // time flip reverses polarity
        c[2u * k + (s ? 1u : 0u)] += 1u;
      }
      const uint out0 = ((p.out_job + j) * 2u * BINS) * plane + pix;
      for (uint k = 0u; k < 2u * BINS; ++k) o[out0 + k * plane] = float(c[k]);
    }
  }
}
