#version 450
// Row-aware event binning (reference section 4) for a chunk of jobs, one pass over the events.
// Exact by construction: the host turned every rational row time into integer thresholds
// (kernels/event_tensor.cpp), so an event's selection, sign and bin are 32-bit int compares.
// Record of (job, row), N + 2 ints: [lo, hi, N-1 ascending thresholds, flags (bit0: a > b)].
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Events { uvec2 ev[]; };   // (t - origin, x | y<<15 | pos<<30)
layout(std430, binding = 1) readonly buffer Records { int rec[]; };
layout(std430, binding = 2) buffer Counts { uint counts[]; };         // [jobs, 2N, h, w]
layout(push_constant) uniform P {
  uint n_events;
  uint jobs;       // jobs in this chunk
  uint job_begin;  // first job of the chunk in the record table
  uint bins;       // N
  uint width, height;
} p;

void main() {
  const uint plane = p.width * p.height;
  const uint rsize = p.bins + 2u;
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
      // How many thresholds are <= t (lower bound over N-1 ascending ints).
      uint first = 0u, count = p.bins - 1u;
      while (count > 0u) {
        const uint step = count >> 1;
        if (rec[base + 2u + first + step] <= t) {
          first += step + 1u;
          count -= step + 1u;
        } else {
          count = step;
        }
      }
      const bool backward = (rec[base + p.bins + 1u] & 1) != 0;
      const uint k = backward ? p.bins - 1u - first : first;
      const bool s = backward ? !positive : positive;  // time flip reverses polarity
      atomicAdd(counts[(j * 2u * p.bins + 2u * k + (s ? 1u : 0u)) * plane + pix], 1u);
    }
  }
}
