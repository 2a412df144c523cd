#version 450
// Row-aware event binning (reference section 4) for a chunk of jobs, one pass over the events.
// Exact by construction: the host turned every rational row time into integer thresholds
// (kernels/event_tensor.cpp), so an event's selection, sign and bin are 32-bit int compares.
// Record of (job, row), N + 4 ints: [lo, hi, N-1 ascending thresholds, flags (bit0: a > b), s, c].
// Counts accumulate directly as float32 through a 32-bit compare-and-swap loop (core Vulkan, no
// float-atomics extension), exact for counts below 2^24; the output needs only a zero fill.
// The host bounds events per invocation and jobs per dispatch: lavapipe silently ends an
// invocation's loops after 65535 iterations in all (kernels/event_tensor.cpp, kLoopBudget).
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Events { uvec2 ev[]; };   // (t - origin, x | y<<15 | pos<<30)
layout(std430, binding = 1) readonly buffer Records { int rec[]; };
layout(std430, binding = 2) buffer Counts { uint counts[]; };         // float32 bits [jobs, 2N, h, w]
layout(push_constant) uniform P {
  uint n_events;
  uint jobs;       // jobs in this chunk
  uint job_begin;  // first job of the chunk in the record table
  uint bins;       // N
  uint width, height;
  uint out_job;    // index of job_begin's job in the output chunk (a dispatch takes a few jobs)
} p;

void main() {
  const uint plane = p.width * p.height;
  const uint rsize = p.bins + 4u;
  const uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  for (uint i = gl_GlobalInvocationID.x; i < p.n_events; i += stride) {
    const uvec2 e = ev[i];
    const int t = int(e.x);
    const uint x = e.y & 0x7fffu;
    const uint y = (e.y >> 15) & 0x7fffu;
    const bool positive = ((e.y >> 30) & 1u) != 0u;
    const uint pix = y * p.width + x;
    for (uint j = 0u; j < p.jobs; ++j) {
      const uint base = ((p.job_begin + j) * p.height + y) * rsize;
      if (t < rec[base] || t >= rec[base + 1u]) continue;  // half-open, empty when lo == hi
      // Threshold count j = #{thresholds <= t}: a float estimate, then exact integer steps
      // (the estimate is within one of the truth; two steps each way leave a margin).
      const float sc = uintBitsToFloat(uint(rec[base + p.bins + 2u]));
      const float c0 = uintBitsToFloat(uint(rec[base + p.bins + 3u]));
      int jt = clamp(int(floor(float(t - rec[base]) * sc + c0)), 0, int(p.bins) - 1);
      for (int r = 0; r < 2; ++r) if (jt < int(p.bins) - 1 && rec[base + 2u + uint(jt)] <= t) ++jt;
      for (int r = 0; r < 2; ++r) if (jt > 0 && rec[base + 1u + uint(jt)] > t) --jt;
      const uint first = uint(jt);
      const bool backward = (rec[base + p.bins + 1u] & 1) != 0;
      const uint k = backward ? p.bins - 1u - first : first;
      const bool s = backward ? !positive : positive;  // time flip reverses polarity
      const uint idx = ((p.out_job + j) * 2u * p.bins + 2u * k + (s ? 1u : 0u)) * plane + pix;
      uint old = counts[idx];
      while (true) {
        const uint prev = atomicCompSwap(counts[idx], old, floatBitsToUint(uintBitsToFloat(old) + 1.0));
        if (prev == old) break;
        old = prev;
      }
    }
  }
}
