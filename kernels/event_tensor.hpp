// Row-aware event tensors (reference section 4): ev1, ev2, ev3 for a batch of (frame, target)
// pairs, on the GPU in one pass over the events, and the exact CPU reference.
//
// For one tensor each sensor row y has a source time a[y] and a key time b[y]. An event at row y
// with integer time t is used iff min(a,b) <= t < max(a,b) (a == b: nothing); its sign is +1 for
// p > 0 else -1, flipped when t < a; its bin is k = floor(|t - a| * N / |b - a|), N -> N - 1;
// it adds 1 at channel 2k + (sign > 0), pixel (y, x).
//
// Exactness: a[y] and b[y] are Rationals (host/row_timing.hpp) and event times are integers, so
// every decision above is a comparison of the integer t with a rational. The CPU reference
// evaluates the formula literally in 128-bit integers over a common denominator. The GPU path
// precomputes, per (job, row), the integer thresholds where the answer changes:
//   selected  <=>  ceil(min(a,b)) <= t < ceil(max(a,b))
//   a < b:  bin >= k  <=>  t >= ceil(a + k|b-a|/N)           (k = 1..N-1)
//   a > b:  bin >= k  <=>  t <  floor(a - k|b-a|/N) + 1      (and every selected t < a: flip)
// relative to a batch origin, so the shader only compares 32-bit ints (no int64, no float).
// Both are exact rational arithmetic; they agree with the reference's float64 wherever float64
// represents a[y], b[y] exactly (integer and dyadic times) — see docs/event_tensors.md.
#pragma once
#include <cstdint>
#include <optional>
#include <vector>

#include "host/events.hpp"
#include "host/row_timing.hpp"
#include "runtime/tensor.hpp"

namespace vkunroll {

class Context;
class Profiler;

// A window of the sensor: rows and columns keep their full-sensor coordinates and times.
struct SensorCrop {
  int x0 = 0, y0 = 0;
  int width = 0, height = 0;  // 0: up to the sensor's edge
};

struct EventTensorSpec {
  int bins = 16;     // N: each tensor has 2N channels
  SensorCrop crop;
};

// One tensor's source and key time for every FULL-sensor row (size = sensor height).
struct RowIntervals {
  std::vector<Rational> a, b;
};

// One (RS frame, target) pair.
struct EventTensorPair {
  RowTiming timing;                           // the RS frame's row timing
  Rational target_us;                         // t*
  std::optional<Rational> target_exposure_us;  // ev3's window length; default timing.exposure
};

// ev1: a = t*, b = start[y]; ev2: a = t*, b = end[y]; ev3: a = t*, b = t* + target exposure.
RowIntervals ev1_intervals(const EventTensorPair& pair);
RowIntervals ev2_intervals(const EventTensorPair& pair);
RowIntervals ev3_intervals(const EventTensorPair& pair);
// Jobs of a batch, tensor-major: ev1 of every pair, then ev2 of every pair, then ev3.
std::vector<RowIntervals> event_tensor_jobs(const std::vector<EventTensorPair>& pairs);

// The resolved crop (checked against the sensor; throws Error naming the bad field).
SensorCrop resolve_crop(const SensorCrop& crop, int sensor_width, int sensor_height);

// Float32 tensors [pairs, 2N, h, w] each (crop size h x w).
struct EventTensors {
  int pairs = 0, bins = 0, height = 0, width = 0;
  std::vector<float> ev1, ev2, ev3;
  size_t events_considered = 0;  // events inside the batch's time window (and crop)
  size_t slice() const { return static_cast<size_t>(2 * bins) * height * width; }
};

// The event times a batch needs: [first, last) in microseconds (first >= last: none). Read only
// this window from the event file.
std::pair<int64_t, int64_t> event_time_window(const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec,
                                              int sensor_width, int sensor_height);

// ---- CPU reference ----------------------------------------------------------------------------
// [jobs, 2N, h, w] float32 counts, the section-4 formula evaluated literally and exactly.
std::vector<float> bin_events_cpu(const EventStream& events, const std::vector<RowIntervals>& jobs,
                                  const EventTensorSpec& spec);
EventTensors build_event_tensors_cpu(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                                     const EventTensorSpec& spec);

// ---- GPU ---------------------------------------------------------------------------------------
// The host part of the GPU path, exposed for tests: per (job, crop row) records of N + 2 int32
// [lo, hi, N-1 ascending thresholds, flags(bit0: a > b)], relative to `origin_us`, and the index
// range [first, last) of the sorted event stream the batch needs (binary search on t).
struct BinningPlan {
  int bins = 0, height = 0, width = 0, x0 = 0, y0 = 0;
  int64_t origin_us = 0;
  size_t first_event = 0, last_event = 0;
  size_t jobs = 0;
  std::vector<int32_t> records;  // [jobs][h][N + 2]
  int record_size() const { return bins + 2; }
};
BinningPlan plan_binning(const EventStream& events, const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec);
// Events of the plan's window inside the crop, packed for the shader: (t - origin, x | y << 15 |
// positive << 30), crop-relative x and y. Returns how many events were packed.
size_t pack_events(const EventStream& events, const BinningPlan& plan, std::vector<uint32_t>& packed);

class EventTensorBuilder {
 public:
  explicit EventTensorBuilder(Context& ctx, Profiler* profiler = nullptr) : ctx_(ctx), profiler_(profiler) {}

  // [jobs, 2N, h, w] float32, identical to bin_events_cpu. Splits jobs into chunks that fit one
  // storage-buffer binding; events are uploaded once for all chunks.
  std::vector<float> bin(const EventStream& events, const std::vector<RowIntervals>& jobs,
                         const EventTensorSpec& spec);
  EventTensors build(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                     const EventTensorSpec& spec);
  // Device-resident result for the network: one f32 tensor [3 * pairs, 2N, h, w] whose ev1, ev2,
  // ev3 are the consecutive ranges of `pairs` slices each. Throws if it exceeds one binding.
  Tensor build_on_device(const EventStream& events, const std::vector<EventTensorPair>& pairs,
                         const EventTensorSpec& spec);

  size_t last_events_considered() const { return last_events_; }
  // Limits below the device's (0: device limits); tests use them to exercise chunking.
  void set_chunk_limits(size_t max_jobs_per_chunk, size_t max_events_per_dispatch) {
    max_jobs_ = max_jobs_per_chunk;
    max_events_ = max_events_per_dispatch;
  }

 private:
  // Bins jobs [job_begin, job_begin + out.shape().n) of `plan` into `out` (u32 counts converted
  // to float32 in place).
  void record_chunk(class CommandStream& cs, const Tensor& packed, size_t n_events, const Tensor& records,
                    const BinningPlan& plan, size_t job_begin, Tensor& out);
  Context& ctx_;
  Profiler* profiler_;
  size_t last_events_ = 0;
  size_t max_jobs_ = 0, max_events_ = 0;
};

}  // namespace vkunroll
