#version 450
// Row-aware event binning into a PERSISTENT output that is all zeros except where the previous
// build counted (event_tensor_undo.comp put those cells back to zero first), so no dense fill:
// the work is O(selected events), not O(pixels x bins). Same (job, row) items per workgroup, exact
// integer thresholds and float32 compare-and-swap accumulation as event_tensor_rows.comp; in
// addition every counted cell's index goes to `touched`, the undo list of the next build.
// Record of (job, row), N + 4 ints: [lo, hi, N-1 ascending thresholds, flags (bit0: a > b), s, c].
// Workgroup z takes the z-th piece of ROW_PIECE events of each range (lavapipe's 65535 loop
// iterations per invocation, see event_tensor_rows.comp).
layout(local_size_x = 64) in;
const uint ROW_PIECE = 16384u;  // kRowPiece in kernels/event_tensor.cpp
layout(std430, binding = 0) readonly buffer Events { uvec2 ev[]; };    // (t - origin, x | positive << 31)
layout(std430, binding = 1) readonly buffer Records { int rec[]; };
layout(std430, binding = 2) readonly buffer Ranges { uvec4 range[]; }; // [jobs][h]: begin, end, touched base, -
layout(std430, binding = 3) buffer Counts { uint counts[]; };          // float32 bits [jobs, 2N, h, w]
layout(std430, binding = 4) writeonly buffer Touched { uint touched[]; };
layout(push_constant) uniform P {
  uint job_begin;  // first job of the chunk in the record table
  uint bins;       // N
  uint width, height;
  uint jobs;       // jobs in the chunk
} p;

void main() {
  const uint plane = p.width * p.height;
  // Workgroups loop over (job, row) items: on lavapipe each workgroup has a fixed cost that a
  // row's few hundred events do not hide, so the host dispatches only a few dozen of them.
  for (uint item = gl_WorkGroupID.x; item < p.jobs * p.height; item += gl_NumWorkGroups.x) {
  const uint y = item % p.height;
  const uint j = item / p.height;  // job within the chunk
  const uint jr = (p.job_begin + j) * p.height + y;
  const uint base = jr * (p.bins + 4u);
  const uvec4 r = range[jr];
  const int lo = rec[base];
  const bool backward = (rec[base + p.bins + 1u] & 1) != 0;
  const float sc = uintBitsToFloat(uint(rec[base + p.bins + 2u]));
  const float c0 = uintBitsToFloat(uint(rec[base + p.bins + 3u]));
  const uint out0 = (j * 2u * p.bins) * plane + y * p.width;
  const int last = int(p.bins) - 1;
  const uint piece_begin = r.x + gl_WorkGroupID.z * ROW_PIECE;
  const uint piece_end = min(r.y, piece_begin + ROW_PIECE);
  for (uint i = piece_begin + gl_LocalInvocationID.x; i < piece_end; i += gl_WorkGroupSize.x) {
    const uvec2 e = ev[i];
    const int t = int(e.x);
    // Threshold count jt = #{thresholds <= t}: a float estimate (within one of the truth), then
    // exact integer steps; two each way leave a margin.
    int jt = clamp(int(floor(float(t - lo) * sc + c0)), 0, last);
    for (int s = 0; s < 2; ++s) if (jt < last && rec[base + 2u + uint(jt)] <= t) ++jt;
    for (int s = 0; s < 2; ++s) if (jt > 0 && rec[base + 1u + uint(jt)] > t) --jt;
    const bool positive = (e.y >> 31) != 0u;
    const uint k = backward ? uint(last - jt) : uint(jt);
    const bool sign = backward ? !positive : positive;  // time flip reverses polarity
    const uint idx = out0 + (2u * k + (sign ? 1u : 0u)) * plane + (e.y & 0x7fffffffu);
    touched[r.z + (i - r.x)] = idx;
    uint old = counts[idx];
    while (true) {
      const uint prev = atomicCompSwap(counts[idx], old, floatBitsToUint(uintBitsToFloat(old) + 1.0));
      if (prev == old) break;
      old = prev;
    }
  }
  }
}
